"""A design session's fit streamed to its views (`studio.design_view.Session`), without a
browser or a viser server: views that note what they are asked to draw. Each iterate is shown
within the share of the fit's time `SHOW_SHARE` allows; a newer edit cancels the fit after its
first accepted iterate and the next fit goes on from that iterate."""

from __future__ import annotations

import time

import numpy as np
import pytest

from studio.design_view import SHOW_SHARE, Session, show_due

HIGH_SIT = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


class NotingView:
    """What a `DesignView` is asked by its session, in order, with the time; showing an
    iterate takes `show_s` seconds (a slow browser connection), and `on_show` runs then."""

    def __init__(self, show_s: float = 0.0, on_show=None):
        self.show_s, self.on_show = show_s, on_show
        self.calls: list[tuple] = []

    def fitting(self, iteration, energy) -> None:
        self.calls.append(("fitting", iteration))

    def show_iterate(self, it) -> None:
        start = time.perf_counter()
        self.calls.append(("iterate", it))
        if self.on_show is not None:
            self.on_show(it)
        time.sleep(max(0.0, self.show_s - (time.perf_counter() - start)))

    def fitted(self, source=None) -> None:
        self.calls.append(("fitted", None))

    def overtaken(self) -> None:
        self.calls.append(("overtaken", None))

    def shown(self) -> list:
        return [it for what, it in self.calls if what == "iterate"]


@pytest.fixture
def session():
    s = Session(None)
    s.design.new_grid((0.5, 0.6), (8, 6), 0.42)
    s.design.add_person(HIGH_SIT, position=[0.0, 0.0, -0.1], support=["seat"])
    yield s
    s.close()


def test_showing_stays_within_its_share_of_the_fit():
    assert show_due(0.0, 0.0)  # the first iterate is always shown
    assert show_due(0.02, 0.1) and not show_due(0.03, 0.1)
    assert show_due(0.3, 1.0, share=0.3) and not show_due(0.31, 1.0, share=0.3)


def test_a_fit_streams_its_iterates_within_the_share_then_draws_the_fit(session):
    show_s = 0.2  # a costly showing: most iterates are left out
    view = NotingView(show_s)
    session.views.append(view)
    start = time.perf_counter()
    assert session.fit()
    elapsed = time.perf_counter() - start
    whats = [what for what, _ in view.calls]
    assert whats[0] == "fitting" and whats[-1] == "fitted" and "iterate" in whats
    shown = view.shown()
    accepted = [it for what, it in view.calls if what == "fitting" and it is not None]
    assert [it.iteration for it in shown] == sorted({it.iteration for it in shown})
    assert {it.iteration for it in shown} <= set(accepted)
    # within the share, but for the one showing that may overdraw it
    assert session.showing_s <= SHOW_SHARE * elapsed + show_s + 0.05
    assert len(shown) < len(accepted), (len(shown), len(accepted), elapsed)
    assert session.shown == len(shown) and session.fits == 1
    result = session.design.last.result
    np.testing.assert_array_equal(shown[0].surface_faces, result.surface_faces)


def test_a_newer_edit_cancels_the_fit_after_its_first_iterate_and_the_next_goes_on(session):
    def newer_edit(it) -> None:  # an edit arrives while the first iterate is shown
        if len(view.shown()) == 1:
            session.design.update_person(0, position=[0.0, 0.0, -0.09])
            session.refitter.bump()

    view = NotingView(on_show=newer_edit)
    session.views.append(view)
    assert not session.fit()
    shown = view.shown()
    assert len(shown) == 1 and shown[0].iteration == 1  # cancelled after its first iterate
    assert ("fitted", None) not in view.calls
    assert view.calls[-1] == ("overtaken", None)  # no fit follows: the last one shows again
    design = session.design
    assert design.last is None  # nothing was evaluated
    np.testing.assert_array_equal(design.resume.control, shown[0].control)
    assert design._warm_start() is design.resume  # the next fit goes on from it
    view.on_show = None
    assert session.fit()
    assert view.calls[-1] == ("fitted", None) and session.fits == 1
    assert design.resume is None and design.last.people[0].spec.position == (0.0, 0.0, -0.09)


def test_the_fit_button_waits_for_the_fit_it_cancels_and_fits_alone(session, monkeypatch):
    """A fit started while another runs (the Fit button during the worker's refit) cancels it
    and waits for it to end: two fits never share the session's last set-up at once."""
    import threading

    running, most = [0], [0]
    fit = type(session.design).fit

    def counted(self, *args, **kwargs):
        running[0] += 1
        most[0] = max(most[0], running[0])
        try:
            return fit(self, *args, **kwargs)
        finally:
            running[0] -= 1

    monkeypatch.setattr(type(session.design), "fit", counted)
    started = threading.Event()
    view = NotingView(on_show=lambda it: started.set())
    session.views.append(view)
    outcomes = {}
    first = threading.Thread(target=lambda: outcomes.setdefault("first", session.fit()))
    first.start()
    assert started.wait(60)  # the first fit has shown an iterate: it is running
    outcomes["second"] = session.fit()  # bumps the generation: the first is cancelled
    first.join(60)
    assert most[0] == 1
    assert outcomes == {"first": False, "second": True}
    assert session.fits == 1 and view.calls[-1] == ("fitted", None)
