"""The fit's overlapped searches (`solver.threads.overlapped`): a fit that judges its steps on
two threads gives the very same surface, step for step, as one that judges them in turn, and
leaves no thread behind; a candidate refused before its depths are measured is refused as it
would be after."""

import threading
import time
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


def _same(one, two):
    assert one.iterations == two.iterations
    assert one.stop_reason == two.stop_reason
    assert one.energies == two.energies
    assert one.qp_statuses == two.qp_statuses
    assert one.energy_terms["rejected_steps"] == two.energy_terms["rejected_steps"]
    np.testing.assert_array_equal(one.control, two.control)
    np.testing.assert_array_equal(one.surface, two.surface)
    np.testing.assert_array_equal(one.state.floor_member, two.state.floor_member)


@pytest.mark.parametrize("name", [
    "single_seated",  # dense (DAQP): a rim, a floor, steps refused for energy and for a fold
    pytest.param("six_overlapping", marks=pytest.mark.slow)])  # sparse (OSQP)
def test_overlapped_searches_give_the_same_fit_bit_for_bit(monkeypatch, name):
    alone = _fits(monkeypatch, name, overlap=False)
    both = _fits(monkeypatch, name, overlap=True)
    assert sum(alone[0].energy_terms["rejected_steps"].values()) > 0
    for one, two in zip(alone, both):
        _same(one, two)


def test_refusing_before_the_depths_changes_nothing(monkeypatch):
    """The loop's candidates with and without the early refusal (`assess`'s ceiling): the same
    steps accepted and refused, the same surface."""
    with_ceiling = _fits(monkeypatch, "single_seated", overlap=False)
    assess = fit_module.assess
    early = []

    def no_ceiling(*args, ceiling=None, **kwargs):
        it = assess(*args, ceiling=ceiling, **kwargs)
        if ceiling is not None:  # how many the ceiling would have refused
            tau, most = ceiling
            early.append((1 - tau) * it.point + tau * it.plane + it.rest > most)
        return assess(*args, **kwargs)

    monkeypatch.setattr(fit_module, "assess", no_ceiling)
    without = _fits(monkeypatch, "single_seated", overlap=False)
    assert any(early), "the premise: some candidates are refused before their depths"
    for one, two in zip(with_ceiling, without):
        _same(one, two)


def test_the_second_thread_ends_with_the_fit(monkeypatch):
    before = set(threading.enumerate())
    _fits(monkeypatch, "single_seated", overlap=True)
    left = [t for t in set(threading.enumerate()) - before
            if t.name.startswith("sitrelax-fit") and t.is_alive()]
    assert not left, left


def test_an_error_while_judging_waits_for_the_other_thread(monkeypatch):
    """The pairing fails while the depths and rows are being made on the pool's thread: the
    error leaves `assess` only once that thread is done writing the rows' members, and it is
    the pairing's."""
    finished, at_error = [], []
    side, assess = fit_module._body_side, fit_module.assess

    def slow_side(*args):
        time.sleep(0.05)
        result = side(*args)
        finished.append(True)
        return result

    def broken_pair(*args):
        raise RuntimeError("pairing failed")

    def watched_assess(*args, **kwargs):
        try:
            return assess(*args, **kwargs)
        except RuntimeError:
            at_error.append(len(finished))
            raise

    monkeypatch.setattr(fit_module, "_body_side", slow_side)
    monkeypatch.setattr(fit_module, "pair", broken_pair)
    monkeypatch.setattr(fit_module, "assess", watched_assess)
    with pytest.raises(RuntimeError, match="pairing failed"):
        _fits(monkeypatch, "single_seated", overlap=True)
    assert at_error == [1]
