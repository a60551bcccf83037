"""The malformed corpus: each file fails with a BvhParseError naming its file and line."""

import json
import re

import pytest

from capture import BvhParseError, read_bvh

from tests.conftest import FIXTURES

CORPUS = FIXTURES / "bvh" / "malformed"
EXPECTED = json.loads((CORPUS / "expected.json").read_text())


def test_corpus_is_complete():
    files = sorted(p.name for p in CORPUS.glob("*.bvh"))
    assert files == sorted(EXPECTED)
    assert len(files) >= 12


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_malformed_file_names_the_line(name):
    path = CORPUS / name
    expected = EXPECTED[name]
    with pytest.raises(BvhParseError) as info:
        read_bvh(path)
    err = info.value
    assert isinstance(err, ValueError)
    assert err.line == expected["line"], str(err)
    assert re.search(expected["message"], err.message), err.message
    assert str(err).startswith(f"{path}:{expected['line']}: ")


def test_directory_is_a_clear_error(tmp_path):
    with pytest.raises(BvhParseError, match="got a directory"):
        read_bvh(tmp_path)
