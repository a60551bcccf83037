"""The fit's overlapped searches (`solver.threads.overlapped`): a fit that judges its steps on
two threads gives the very same surface, step for step, as one that judges them in turn, and
leaves no thread behind."""

import threading
from pathlib import Path

import numpy as np
import pytest

import solver.surface.fit as fit_module
from solver.scene.placement import place_scene
from solver.scene.run import fit_people
from solver.scene.scenario import load_scenario

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"


def _fits(monkeypatch, name: str, overlap: bool):
    """An example fitted cold, then refitted warm with its first person moved 2 cm, with the
    searches overlapped or not."""
    from dataclasses import replace

    from solver.scene.placement import place_person

    monkeypatch.setattr(fit_module, "overlapped", lambda: overlap)
    scenario, people = place_scene(load_scenario(EXAMPLES / f"{name}.toml"))
    cold = fit_people(scenario, people)
    spec = scenario.persons[0]
    moved = replace(spec, position=tuple(np.asarray(spec.position) + [0.0, 0.0, 0.02]))
    warm = fit_people(scenario, [place_person(moved, None, 0)] + people[1:], warm=cold)
    return cold, warm


def test_overlapped_searches_give_the_same_fit_bit_for_bit(monkeypatch):
    # single_seated has a rim, a floor and refused steps (for their energy and for a fold)
    alone = _fits(monkeypatch, "single_seated", overlap=False)
    both = _fits(monkeypatch, "single_seated", overlap=True)
    assert sum(alone[0].energy_terms["rejected_steps"].values()) > 0
    for one, two in zip(alone, both):
        assert one.iterations == two.iterations
        assert one.stop_reason == two.stop_reason
        assert one.energies == two.energies
        assert one.qp_statuses == two.qp_statuses
        np.testing.assert_array_equal(one.control, two.control)
        np.testing.assert_array_equal(one.surface, two.surface)
        np.testing.assert_array_equal(one.state.floor_member, two.state.floor_member)


def test_the_second_thread_ends_with_the_fit(monkeypatch):
    before = {t.name for t in threading.enumerate()}
    _fits(monkeypatch, "single_seated", overlap=True)
    left = {t.name for t in threading.enumerate()} - before
    assert not any(name.startswith("sitrelax-fit") for name in left), left


def test_an_error_while_judging_waits_for_the_other_thread(monkeypatch):
    """The pairing fails while the depths and rows are being made on the pool's thread: the
    error reaches the caller only once that thread is done writing the rows' members."""
    finished = []
    side = fit_module._body_side

    def slow_side(*args):
        result = side(*args)
        finished.append(True)
        return result

    def broken_pair(*args):
        raise RuntimeError("pairing failed")

    monkeypatch.setattr(fit_module, "_body_side", slow_side)
    monkeypatch.setattr(fit_module, "pair", broken_pair)
    with pytest.raises(RuntimeError, match="pairing failed"):
        _fits(monkeypatch, "single_seated", overlap=True)
    assert finished == [True]
