"""Every name the `solver` facade exports is documented: functions in numpydoc sections
(`Parameters`, `Returns`), classes with a docstring of their own."""

import inspect
import re

import pytest

import solver

# Their docstrings land separately (solver/scene/run.py and solver/scene/scenario.py are being
# edited elsewhere); remove this set once they have numpydoc sections.
# Exported values that are neither functions nor classes.
CONSTANTS = {"BODY_PARTS", "BODY_REGIONS"}


def _section(doc: str, name: str) -> bool:
    return re.search(rf"^{name}\n-{{3,}}$", doc, re.MULTILINE) is not None


def _kind(name: str) -> str:
    value = getattr(solver, name)
    if inspect.isclass(value):
        return "class"
    if inspect.isfunction(inspect.unwrap(value)):  # make_body is an lru_cache wrapper
        return "function"
    return "constant"


FUNCTIONS = [n for n in solver.__all__ if _kind(n) == "function"]
CLASSES = [n for n in solver.__all__ if _kind(n) == "class"]


def test_every_export_is_a_function_a_class_or_a_known_constant():
    constants = {n for n in solver.__all__ if _kind(n) == "constant"}
    assert constants == CONSTANTS


@pytest.mark.parametrize("name", FUNCTIONS)
def test_function_has_parameters_and_returns_sections(name):
    func = getattr(solver, name)
    doc = inspect.getdoc(func)
    assert doc, f"{name} has no docstring"
    if inspect.signature(func).parameters:
        assert _section(doc, "Parameters"), f"{name}'s docstring has no Parameters section"
    assert _section(doc, "Returns"), f"{name}'s docstring has no Returns section"


@pytest.mark.parametrize("name", CLASSES)
def test_class_has_a_docstring(name):
    cls = getattr(solver, name)
    doc = cls.__dict__.get("__doc__")
    assert doc and doc.strip(), f"{name} has no docstring"
    # a dataclass without a docstring gets its signature as one
    assert not doc.startswith(f"{name}("), f"{name} has only the generated docstring"
