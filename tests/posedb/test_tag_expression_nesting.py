"""Tag expressions nested or chained beyond what recursion allows are refused or matched,
never a RecursionError; a refused tag is told what a tag is made of."""

import numpy as np
import pytest

from posedb.tags import TagError, compile_expression, membership

MAX_NESTING = 100  # posedb.tags.MAX_NESTING, as the README states it


@pytest.mark.parametrize("expr", [
    "not " * 3000 + "sit",
    "(" * 1000 + "sit" + ")" * 1000,
    "(not " * 600 + "sit" + ")" * 600,
])
def test_nesting_past_the_limit_is_refused_naming_the_limit(expr):
    with pytest.raises(TagError, match=rf"at most {MAX_NESTING} parentheses and 'not's"):
        compile_expression(expr)


def test_nesting_up_to_the_limit_matches():
    m, vocab = membership([["sit"], ["lie"]])
    even = compile_expression("not " * MAX_NESTING + "sit")
    assert even(m, vocab).tolist() == [True, False]
    inside = compile_expression("(" * MAX_NESTING + "lie" + ")" * MAX_NESTING)
    assert inside(m, vocab).tolist() == [False, True]


def test_long_chains_match_without_recursing_per_operand():
    m, vocab = membership([["a"], ["b"], []])
    ors = compile_expression(" or ".join(["x"] * 5000 + ["b"]))
    assert ors(m, vocab).tolist() == [False, True, False]
    ands = compile_expression(" and ".join(["a"] * 5000))
    assert ands(m, vocab).tolist() == [True, False, False]
    mixed = compile_expression("a and not b or " * 2000 + "b")
    assert mixed(m, vocab).dtype == np.bool_
    assert mixed(m, vocab).tolist() == [True, True, False]


def test_db_list_with_a_too_deep_expression_exits_2_with_json(tmp_path, capsys):
    import json

    from studio.cli import main

    db = tmp_path / "lib.h5"
    assert main(["db", "import", "bundled:cmu_82_05_floor_sit_excerpt.bvh", "--db", str(db)]) == 0
    capsys.readouterr()
    code = main(["db", "list", "--db", str(db), "--json", "--tag", "(" * 500 + "sit" + ")" * 500])
    out = capsys.readouterr().out
    assert code == 2
    assert "at most" in json.loads(out)["error"]


@pytest.mark.parametrize("tag", ["café", "ＳＩＴ", "-x", ".x"])
def test_a_refused_tag_is_told_which_letters_and_first_characters_a_tag_takes(tag):
    from posedb.tags import normalise_tag

    with pytest.raises(TagError, match=r"ASCII letters \(a-z\).*starting with a letter, digit"):
        normalise_tag(tag)

