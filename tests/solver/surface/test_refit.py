"""Warm refits (a person moved, a control vertex edited) and cancelled fits, on the seated
example: a warm refit settles where a cold fit of the new scene does, in fewer iterations."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from solver.scene.placement import place_person, place_scene
from solver.scene.run import fit_scene
from solver.scene.scenario import load_scenario
from solver.surface.fit import FitError, fit_surface
from solver.surface.subdivision import grid_mesh

SCENARIOS = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
FIGURES = ("coverage", "contact_coverage", "max_penetration_m")


@pytest.fixture(scope="module")
def seated():
    """single_seated fitted cold, and its person moved 2 cm forward (along +Z, the way the
    person faces) and placed again."""
    scenario, people = place_scene(load_scenario(SCENARIOS / "single_seated.toml"))
    first, _, _ = fit_scene(scenario, people)
    spec = scenario.persons[0]
    moved = replace(spec, position=tuple(np.asarray(spec.position) + [0.0, 0.0, 0.02]))
    return scenario, first, [place_person(moved, None, 0)]


@pytest.fixture(scope="module")
def refits(seated):
    """The moved scene fitted cold and warm (from the first fit): (result, figures) each."""
    scenario, first, people = seated
    cold, cold_figures, _ = fit_scene(scenario, people)
    warm, warm_figures, _ = fit_scene(scenario, people, warm=first)
    return (cold, cold_figures[0]), (warm, warm_figures[0])


def test_a_warm_refit_after_a_move_matches_a_cold_fit_in_fewer_iterations(seated, refits):
    (cold, cold_figures), (warm, warm_figures) = refits
    margin = seated[0].surface.params.margin
    assert warm.stop_reason.startswith("settled"), warm.stop_reason
    assert warm.iterations < cold.iterations
    # (a cold fit's proposals are made stiffer where they fold, a warm refit holds such places
    # still instead, and the rim rows hold its front edge where the last fit left it: they may
    # end apart; here the refit covers 0.956 against the cold fit's 0.954, both over the bar)
    assert warm_figures["coverage"] >= cold_figures["coverage"] - 0.02
    assert warm_figures["coverage"] >= 0.95 and warm_figures["contact_coverage"] >= 0.8
    assert warm_figures["contact_coverage"] >= cold_figures["contact_coverage"] - 0.03
    # within the softness the fit allows (both cut the body less deeply than the margin)
    assert warm_figures["max_penetration_m"] <= max(cold_figures["max_penetration_m"], margin)
    # the refit settles near the cold fit's energy or lower (2.9e-4 against 5.0e-4 on this
    # move; with OSQP's inexact steps the cold fit went lower, 2.3e-4 against 3.8e-4)
    assert warm.energies[-1] <= cold.energies[-1] * 1.8
    e = np.asarray(warm.energies)
    assert np.all(e[1:] <= e[:-1])  # judged at tau_max throughout: never rises
    assert warm.energy_terms["tau"] == pytest.approx(cold.energy_terms["tau"])


def test_a_warm_refit_of_an_unchanged_scene_stops_at_once(seated):
    """Nothing moved: within a step or two, a step lowers the energy by less than the
    tolerance (the cold fit stops when five iterations together gain less than 1 %; the rim's
    rows, which hold the surface's edge off the calves from where it lies, let it slide along
    them a little further: three iterations on single_seated)."""
    scenario, first, _ = seated
    _, people = place_scene(scenario)
    again = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                        scenario.surface.params, warm=first)
    assert again.iterations <= 3, again.stop_reason
    assert again.energies[-1] <= first.energies[-1] * 1.01


def test_an_edited_control_vertex_moves_the_warm_start_as_much(seated):
    """A corner far from the person moved 3 cm up in the designer's mesh starts (and, nothing
    pulling it elsewhere, ends) 3 cm above where the first fit left it, not where it was."""
    scenario, first, people = seated
    start = scenario.surface.vertices.copy()
    start[0] += [0.0, 0.03, 0.0]
    result = fit_surface(start, scenario.surface.faces, people, scenario.surface.params,
                         warm=first)
    # (its neighbours, pulled 8 mm into the skin, draw it down by about 5 mm; where it was
    # before the edit is 30 mm away)
    assert np.linalg.norm(result.control[0] - (first.control[0] + [0.0, 0.03, 0.0])) < 0.01


def test_cancel_ends_the_fit_with_the_last_accepted_iterate(seated):
    scenario, _, people = seated
    polls = []

    def cancel():
        polls.append(1)
        return len(polls) > 2  # two iterations run, the third is cancelled

    result = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                         scenario.surface.params, cancel=cancel)
    assert result.stop_reason.startswith("cancelled"), result.stop_reason
    assert result.iterations == 2 and len(result.energies) == 2
    assert not result.energy_terms["repairs"]  # no round of rows after a cancel
    start = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                        scenario.surface.params, cancel=lambda: True)
    assert start.iterations == 0 and start.stop_reason.startswith("cancelled")
    np.testing.assert_array_equal(start.control, scenario.surface.vertices)


def _deadline_cancel(deadline: float):
    """A cancel that never says so itself, with a deadline (as the HTTP API's has)."""
    def cancel():
        return False
    cancel.deadline = deadline
    return cancel


def test_a_deadline_stops_the_small_mesh_s_solve_before_each_daqp_run(seated, monkeypatch):
    """The small meshes' exact solver (DAQP, whose tries take a second or more on a stiff
    programme) asks the deadline before each try: a deadline that passes while a try is under
    way (here a pause that is not DAQP's, which its own time limit cannot stop) stops the fit
    before the next try, cancelled."""
    import time

    import solver.surface.programme as P

    scenario, _, people = seated
    runs = []
    real = P.DenseProgramme._solve_daqp

    def slow_run(self, *args):
        runs.append(1)
        time.sleep(0.3)  # (a stiff programme's run)
        return real(self, *args)

    monkeypatch.setattr(P.DenseProgramme, "_solve_daqp", slow_run)
    cancel = _deadline_cancel(time.monotonic() + 0.5)
    start = time.monotonic()
    result = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                         scenario.surface.params, cancel=cancel)
    assert result.stop_reason.startswith("cancelled"), result.stop_reason
    assert 1 <= len(runs) <= 3 and time.monotonic() - start < 0.5 + 0.3 + 2.0


def test_a_deadline_stops_the_programme_s_solve(seated):
    """A fit on a mesh large enough for OSQP (16 x 12 quads, 221 control vertices) whose
    cancel's deadline has passed stops at its first solve, as a fit cancelled between
    iterations does; one whose deadline is far off solves as without (OSQP's time limit set
    from it, its default again after the fit)."""
    import time

    import solver.surface.fit as F

    scenario, _, people = seated
    grid_v, grid_f = grid_mesh((0.6, 0.6), (16, 12), 0.42)
    params = replace(scenario.surface.params, max_iterations=2)
    stopped = fit_surface(grid_v, grid_f, people, params,
                          cancel=_deadline_cancel(time.monotonic() - 1.0))
    assert stopped.stop_reason.startswith("cancelled after 0 iteration(s)"), stopped.stop_reason
    np.testing.assert_array_equal(stopped.control, grid_v)
    solved = []
    real = F.Programme._solve_rows

    def solve_rows(self, *args):
        out = real(self, *args)
        solved.append(self.solver.settings.time_limit)
        return out

    F.Programme._solve_rows = solve_rows
    try:
        free = fit_surface(grid_v, grid_f, people, params)
        late = fit_surface(grid_v, grid_f, people, params,
                           cancel=_deadline_cancel(time.monotonic() + 1000.0))
    finally:
        F.Programme._solve_rows = real
    assert free.iterations == late.iterations and len(free.energies) == 2
    np.testing.assert_array_equal(free.control, late.control)
    limits = np.array(solved)
    assert len(limits) >= 4 and np.all(limits[:len(limits) // 2] == 1e10)
    assert np.all((limits[len(limits) // 2:] > 900.0) & (limits[len(limits) // 2:] < 1000.0))


def test_a_cancel_stops_the_programme_s_solve_between_runs_of_its_iterations(seated):
    """A large mesh's solve (OSQP, 16 x 12 quads) asks the fit's cancel between runs of its
    iterations: a cancel that says so there ends the fit in its first solve, as one cancelled
    between iterations does; a cancel that never does leaves the fit as without one, bit for
    bit (`test_a_deadline_stops_the_programme_s_solve` compares those)."""
    import inspect

    scenario, _, people = seated
    grid_v, grid_f = grid_mesh((0.6, 0.6), (16, 12), 0.42)
    params = replace(scenario.surface.params, max_iterations=2)
    asked = []

    def cancel():
        inside = any(frame.function == "_solve_polled" for frame in inspect.stack())
        asked.append(inside)
        return inside

    stopped = fit_surface(grid_v, grid_f, people, params, cancel=cancel)
    assert stopped.stop_reason.startswith("cancelled after 0 iteration(s)"), stopped.stop_reason
    assert asked == [False, True]  # before the first iteration, then in its solve
    np.testing.assert_array_equal(stopped.control, grid_v)


def test_a_deadline_that_passes_between_runs_stops_the_fit_whatever_the_moment(seated,
                                                                                monkeypatch):
    """Wherever between the programme's clock readings a deadline passes, the fit ends as
    cancelled (or done), never with OSQP refusing a time limit that is not positive: on a clock
    that moves a second at every reading, with the deadline after each of 2 to 15 readings."""
    import types

    import solver.surface.programme as programme

    scenario, _, people = seated
    grid_v, grid_f = grid_mesh((0.6, 0.6), (16, 12), 0.42)
    params = replace(scenario.surface.params, max_iterations=2)
    for readings in range(2, 16):
        ticks = [0]

        def monotonic():
            ticks[0] += 1
            return 1000.0 + ticks[0]

        monkeypatch.setattr(programme, "time", types.SimpleNamespace(monotonic=monotonic))
        cancel = _deadline_cancel(1000.0 + readings + 0.5)
        result = fit_surface(grid_v, grid_f, people, params, cancel=cancel)
        assert result.stop_reason.startswith(("cancelled", "reached the iteration limit")), \
            (readings, result.stop_reason)


@pytest.mark.slow
def test_a_cancel_ends_a_large_fit_within_a_second_and_a_half():
    """On a 48 x 36 grid (1,813 control vertices) a solve takes 1-6 s and one iteration's tries
    some 45 s (on the machine this was written on). A cancel that says so from 2 s in ends the
    fit within 1.5 s of that (0.9 s measured: the programme's set-up and its first run of
    iterations ask no cancel; 1.0 s with three busy processes on two cores, the last 0.3 s
    of it after the cancel said so, making the result), where it ended only with the solve
    then running (2.0-2.2 s later) before solves asked it."""
    import time

    scenario, people = place_scene(load_scenario(SCENARIOS / "single_seated.toml"))
    grid_v, grid_f = grid_mesh((0.6, 0.6), (48, 36), 0.42)
    params = replace(scenario.surface.params, max_iterations=1)
    began, said = time.monotonic(), []

    def cancel():
        if time.monotonic() - began > 2.0:
            said.append(time.monotonic())
            return True
        return False

    result = fit_surface(grid_v, grid_f, people, params, cancel=cancel)
    ended = time.monotonic()
    assert result.stop_reason.startswith("cancelled after 0 iteration(s)"), result.stop_reason
    assert ended - (began + 2.0) < 1.5 and ended - said[0] < 0.5, (ended - began, said)


def test_a_solve_stopped_at_the_deadline_keeps_the_accepted_iterates(seated, monkeypatch):
    """Stopped at the deadline in its third iteration's solve, a fit ends with the two
    iterations it accepted, as one cancelled there between its tries does."""
    import solver.surface.fit as F
    from solver.surface.programme import DeadlinePassed

    scenario, _, people = seated
    calls = []
    real = F.propose

    def propose(*args):
        calls.append(1)
        if len(calls) == 3:
            raise DeadlinePassed
        return real(*args)

    monkeypatch.setattr(F, "propose", propose)
    result = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                         scenario.surface.params)
    assert result.stop_reason.startswith("cancelled after 2 iteration(s)"), result.stop_reason
    assert result.iterations == 2 and len(result.energies) == 2
    assert not result.energy_terms["repairs"]


def test_a_warm_start_from_another_control_mesh_is_refused(seated):
    scenario, first, people = seated
    grid_v, grid_f = grid_mesh((0.5, 0.6), (4, 3), 0.42)
    with pytest.raises(FitError, match="same control mesh"):
        fit_surface(grid_v, grid_f, people, scenario.surface.params, warm=first)


def test_every_accepted_iterate_reaches_the_iterates_callback(seated):
    """`iterates` sees each accepted iterate once, in order, as copies; the last is the
    result when no crossing was backed out of."""
    scenario, _, people = seated
    seen, energies = [], []
    result = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                         scenario.surface.params,
                         lambda i, e, tau: energies.append(i),
                         iterates=lambda i, control, surface: seen.append((i, control, surface)))
    assert [i for i, _, _ in seen] == energies == list(range(1, len(seen) + 1))
    assert len(seen) == len(result.energies) + sum(
        len(r["energies"]) for r in result.energy_terms["repairs"])
    _, control, surface = seen[-1]
    if "crossed itself" not in result.stop_reason:
        np.testing.assert_array_equal(control, result.control)
        np.testing.assert_allclose(surface, result.surface)
    control[:] = 0.0  # a copy: the result is untouched
    assert np.abs(result.control).max() > 0.1


def test_a_refit_beside_another_sets_up_its_own_programme(seated):
    """The programme a warm refit reuses is claimed by one fit at a time: while another fit
    holds the first fit's, the refit sets up its own (and settles all the same); once given
    back, the next refit reuses it."""
    scenario, first, people = seated
    held = first.state.programme
    assert held.claim()  # another fit solving it now
    try:
        beside = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                             scenario.surface.params, warm=first)
    finally:
        held.release()
    assert beside.state.programme is not held
    assert beside.stop_reason.startswith("settled"), beside.stop_reason
    after = fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                        scenario.surface.params, warm=first)
    assert after.state.programme is held
    assert held.claim()  # given back when the refit ended
    held.release()
