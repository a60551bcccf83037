"""Tags and tag expressions.

A tag is a lower-case word of ASCII letters, digits, `_`, `-`, `.` or `:` (`sit`, `high-seat`,
`session:2026-11`). An expression combines tags with `and`, `or`, `not` and parentheses
(`sit and not floor`, `lean or lounge`, `not (sit or lie)`); `and` binds tighter than `or`.
Expressions compile to a function over a boolean membership matrix (items x vocabulary), so a
search over a whole library is a handful of vectorised operations.
"""

from __future__ import annotations

import functools
import re
from typing import Callable, Iterable, Sequence

import numpy as np

from .schema import LibraryError

_TAG = re.compile(r"[a-z0-9_][a-z0-9_.:\-]*")
_TOKEN = re.compile(r"\s*(\(|\)|[^\s()]+)")
KEYWORDS = ("and", "or", "not")
MAX_NESTING = 100  # parentheses and `not`s inside one another: parsed and matched by recursion


class TagError(LibraryError):
    """A tag or tag expression that cannot be used."""


def normalise_tag(tag: str) -> str:
    """The canonical form of a tag (lower case); raises TagError for anything else."""
    text = str(tag).strip().lower()
    if not _TAG.fullmatch(text) or text in KEYWORDS:
        raise TagError(
            f"Expected a tag of ASCII letters (a-z), digits, '_', '-', '.' or ':', starting with "
            f"a letter, digit or '_' (not and/or/not), got {tag!r}"
        )
    return text


MAX_TAG = 64  # characters of a new tag (a word, not a note: the studio lists tags in a line)


def normalise_tags(tags: Iterable[str], new: bool = False,
                   known: Iterable[str] = ()) -> tuple[str, ...]:
    """Sorted, de-duplicated canonical tags; `new`: tags being given, held to MAX_TAG
    characters but for those the library holds already (`known`: a tag stored before is read,
    searched, removed and inherited whatever its length)."""
    out = tuple(sorted({normalise_tag(t) for t in tags}))
    known = set(known) if new else set()
    long = [t for t in out if len(t) > MAX_TAG and t not in known] if new else []
    if long:
        raise TagError(f"Expected tags of at most {MAX_TAG} characters (a word, not a note), "
                       f"got one of {len(long[0])}: {long[0][:40]!r}...")
    return out


Matcher = Callable[[np.ndarray, dict[str, int]], np.ndarray]


def compile_expression(expr: str) -> Matcher:
    """Compiles a tag expression into `match(membership, vocabulary) -> (N,) bool`.

    membership : (N, K) bool, item n carries tag k; vocabulary : tag -> column k.
    """
    text = expr.strip()
    if not text:
        raise TagError("Expected a tag expression, got an empty one")
    tokens = _expression_tokens(text)
    at = 0
    depth = 0

    def peek() -> str | None:
        return tokens[at][0].lower() if at < len(tokens) else None

    def fail(what: str) -> TagError:
        got = repr(tokens[at][0]) if at < len(tokens) else "the end"
        col = tokens[at][1] + 1 if at < len(tokens) else len(text) + 1
        return TagError(f"In tag expression {expr!r} at column {col}: expected {what}, got {got}")

    def parse_infix(keyword: str, operand: Callable[[], Matcher],
                    combine: Callable[[Sequence[Matcher]], Matcher]) -> Matcher:
        nonlocal at
        operands = [operand()]
        while peek() == keyword:
            at += 1
            operands.append(operand())
        # one flat combination, however long the chain: matching it recurses no deeper
        return operands[0] if len(operands) == 1 else combine(operands)

    def nest() -> None:
        nonlocal depth
        depth += 1
        if depth > MAX_NESTING:
            raise fail(f"at most {MAX_NESTING} parentheses and 'not's inside one another")

    def parse_not() -> Matcher:
        nonlocal at, depth
        if peek() == "not":
            nest()
            at += 1
            inner = parse_not()
            depth -= 1
            return _negated(inner)
        return parse_atom()

    def parse_atom() -> Matcher:
        nonlocal at, depth
        tok = peek()
        if tok == "(":
            nest()
            at += 1
            inner = parse_or()
            if peek() != ")":
                raise fail("')'")
            at += 1
            depth -= 1
            return inner
        if tok is None or tok in KEYWORDS or tok == ")":
            raise fail("a tag or '('")
        try:
            tag = normalise_tag(tokens[at][0])
        except TagError:
            raise fail("a tag") from None
        at += 1
        return _carries(tag)

    # Partials, not wrapper functions: a nesting level costs as few frames as it did before.
    parse_and = functools.partial(parse_infix, "and", parse_not, _both)
    parse_or = functools.partial(parse_infix, "or", parse_and, _either)
    result = parse_or()
    if at != len(tokens):
        raise fail("'and', 'or' or the end")
    return result


def _expression_tokens(text: str) -> list[tuple[str, int]]:
    """A tag expression's words and parentheses, each with its 0-based column."""
    tokens = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            break
        tokens.append((m.group(1), m.start(1)))
        pos = m.end()
    return tokens


def _either(operands: Sequence[Matcher]) -> Matcher:
    return lambda m, v: functools.reduce(np.logical_or, (a(m, v) for a in operands))


def _both(operands: Sequence[Matcher]) -> Matcher:
    return lambda m, v: functools.reduce(np.logical_and, (a(m, v) for a in operands))


def _negated(inner: Matcher) -> Matcher:
    return lambda m, v: ~inner(m, v)


def _carries(tag: str) -> Matcher:
    """Items that carry `tag` (none when the vocabulary lacks it)."""

    def match(m: np.ndarray, vocab: dict[str, int]) -> np.ndarray:
        k = vocab.get(tag)
        return np.zeros(m.shape[0], dtype=bool) if k is None else m[:, k].copy()

    return match


def membership(tag_lists: Sequence[Sequence[str]]) -> tuple[np.ndarray, dict[str, int]]:
    """(N, K) bool membership matrix and vocabulary for items' tag lists."""
    vocab: dict[str, int] = {}
    rows, cols = [], []
    for n, tags in enumerate(tag_lists):
        for t in tags:
            rows.append(n)
            cols.append(vocab.setdefault(t, len(vocab)))
    m = np.zeros((len(tag_lists), len(vocab)), dtype=bool)
    if rows:
        m[np.array(rows), np.array(cols)] = True
    return m, vocab
