"""The studio's Design view: one tab's design session (`Design`) drawn and edited with viser.

The scene is Y up, in metres, under `/design`. Each person hangs under a transform gizmo
(dragging moves and turns the body) and has a typed position (x, y, z m) and rotation (degrees,
intrinsic "xyz"). Control vertices are picked by clicking on them (shift-click adds or removes
one, shift-drag a box adds those inside it) or by typing their indices; one gizmo at the
selection's centroid moves all of them, and the selection can be fixed, freed, typed to a new
centroid, creased along the control edges it spans, or split (the quad its corners pick).

While "Refit while dragging" is on, every drag or typed move asks the session's worker thread
for a fit (`Refitter`): the newest edit cancels a fit still running for an older one (the next
fit goes on from the cancelled one's last iterate, warm), and fits start no faster than they
finish, so the machine keeps up. A fit's accepted iterates stream to the tabs as they come: the
surface node's vertices (level s) and the fitted control net are updated in place, as often as
showing them takes at most `SHOW_SHARE` of the fit's time; the finished fit replaces them with
its limit surface (the same quads), the bodies coloured by pressure and the figures. Every
finished fit's surface is then judged by the guarantees the export's report.json holds (no
self-crossing, no fold, no slit, above the floor, no cut past the margin on a dense sampling:
`Design.judge`) on a thread of its own (`Judge`), once no newer fit runs or is asked for, and
what it misses is shown beside each person's misses, in the report's words. Everything goes
through `Design` (the same solver and library calls as the command line).

A tab has its own session; tabs that join the same session name share one (each with its own
selection and status line, all drawing every edit).
"""

from __future__ import annotations

import io
import json
import re
import threading
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from posedb.regions import support_regions
from solver.body.model import BODY_REGIONS, SHAPE_KEYS, BodyShape
from solver.contact.evaluate import flat_text, peak_text
from solver.io.render import SKIN, SURFACE
from solver.mesh import quad_triangles
from solver.scene import schema
from solver.scene.quality import NO_SEAT_POSTURES
from solver.scene.relief import relief_text
from solver.scene.run import pressure_on_skin

from .context import INTERNAL, PROBLEM, LibraryWatch, StudioContext, guarded, notice
from .design import (DEFAULT_POSE, TEMPLATES, Design, DesignError, FitOutcome, Iterate,
                     check_name, control_edges, template_name)

CONTROL_COLOR = (40, 40, 48)
FIXED_COLOR = (220, 50, 40)
FREE_COLOR = (40, 110, 220)
SELECTED_COLOR = (250, 190, 20)
CREASE_COLOR = (200, 30, 160)
FITTED_NET_COLOR = (30, 150, 90)
RELAXED_COLOR = (150, 200, 150)
PICK_ANGLE = 0.03  # radians off a click's ray within which a control vertex is hit
BODY_MODES = {"shown": 1.0, "ghost": 0.25, "hidden": 0.0}  # opacity of the bodies
QUIET_S = 0.03  # a refit waits this long for the drag's next event before it starts
SHOW_SHARE = 0.2  # showing a fit's iterates takes at most this share of the fit's time
STEP_GRACE_S = 0.15  # a newer edit lets a fit run this long for its first accepted iterate
# a refit's surface is judged (`Judge`) once no fit has run or been asked for this long: the
# check (0.1 s for one person, 1.3 s for six) would otherwise hold up a drag's refits
SETTLE_S = 0.3


def _rgb(color) -> tuple[int, int, int]:
    return tuple(int(round(255 * c)) for c in color)


def quat_wxyz(rotation_deg) -> np.ndarray:
    """viser's (w, x, y, z) of a person's `rotation_deg` (intrinsic "xyz", degrees)."""
    x, y, z, w = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_quat()
    return np.array([w, x, y, z])


def euler_deg(wxyz) -> list[float]:
    """A person's `rotation_deg` (intrinsic "xyz", degrees, 3 decimals) of viser's (w, x, y, z)."""
    w, x, y, z = (float(c) for c in wxyz)
    with warnings.catch_warnings():  # (a quarter turn about y is gimbal lock: one of the
        warnings.simplefilter("ignore", UserWarning)  # angles that turn so is given)
        angles = Rotation.from_quat([x, y, z, w]).as_euler("xyz", degrees=True)
    return [round(float(a), 3) for a in angles]


def same_turn(wxyz, rotation_deg, tolerance_deg: float = 1e-4) -> bool:
    """Whether viser's (w, x, y, z) turns as a person's `rotation_deg` (intrinsic "xyz",
    degrees) does, within `tolerance_deg`: a gizmo moved, not turned (its Euler angles read
    back would write (0, 170, 0) as (180, 10, 180))."""
    w, x, y, z = (float(c) for c in wxyz)
    between = Rotation.from_quat([x, y, z, w]).inv() * \
        Rotation.from_euler("xyz", rotation_deg, degrees=True)
    return bool(np.degrees(between.magnitude()) <= tolerance_deg)


def project(points: np.ndarray, position, wxyz, fov: float, aspect: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Where points land on a viser camera's image.

    Parameters
    ----------
    points : (N, 3) float, metres.
    position, wxyz : the camera's position and orientation (viser's: OpenCV axes, +z looking,
        +y down the image).
    fov : vertical field of view, radians; aspect : width over height.

    Returns
    -------
    uv : (N, 2) float, image coordinates in [0, 1] from the top left (OpenCV's, as viser's
    pointer events give them); front : (N,) bool, the points in front of the camera.
    """
    w, x, y, z = (float(c) for c in wxyz)
    local = (np.asarray(points, dtype=np.float64) - np.asarray(position)) @ \
        Rotation.from_quat([x, y, z, w]).as_matrix()
    depth = local[:, 2]
    front = depth > 1e-6
    safe = np.where(front, depth, 1.0)
    half = np.tan(fov / 2.0)
    u = (local[:, 0] / safe / (half * aspect) + 1.0) / 2.0
    v = (local[:, 1] / safe / half + 1.0) / 2.0
    return np.stack([u, v], axis=1), front


def ray_pick(points: np.ndarray, origin, direction, angle: float = PICK_ANGLE) -> int | None:
    """The point seen closest to a ray (smallest angle off it, within `angle` radians, in front
    of its origin), or None. points : (N, 3) metres."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    rel = np.asarray(points, dtype=np.float64) - np.asarray(origin)
    along = rel @ d
    off = np.linalg.norm(rel - along[:, None] * d, axis=1)
    ang = np.where(along > 1e-6, np.arctan2(off, np.maximum(along, 1e-6)), np.inf)
    if not len(ang) or ang.min() > angle:
        return None
    return int(np.argmin(ang))


# what a number looks like while it is typed, before it reads as one: nothing yet, a sign, a
# point, or an exponent without its digits (a text input sends every keystroke)
_PARTIAL_NUMBER = re.compile(r"[+-]?(\d*\.?\d*)?([eE][+-]?)?")


def _short_pose(spec: str) -> str:
    """A pose source as a label shows it: `bvh:bundled:NAME.bvh#frame=N` as `NAME #N`, a
    library pose by its name, anything else cut to 40 characters."""
    text = spec.removeprefix("bvh:").removeprefix("bundled:").removeprefix("db:")
    text = text.replace(".bvh#frame=", " #")
    return text if len(text) <= 40 else text[:37] + "..."


def show_due(spent: float, elapsed: float, share: float = SHOW_SHARE) -> bool:
    """Whether a fit that has run `elapsed` seconds, `spent` of them showing its iterates, shows
    the next one: showing stays within `share` of the fit's time (by at most one showing's
    cost; the first iterate is always shown)."""
    return spent <= share * elapsed


class Refitter:
    """Fits a session on a worker thread: `request` after an edit; the newest request wins (a
    fit still running for an older one is cancelled between its iterations, once it has made a
    step: `Session.fit`) and fits start no more often than the last one took, so a drag never
    queues fits the machine cannot keep up with."""

    def __init__(self, session: "Session"):
        self.session = session
        self.generation = 0  # bumped by every edit a fit must follow
        self._wanted: int | None = None
        self._cond = threading.Condition()
        self._closed = False
        self._last_start = 0.0
        self._last_seconds = 0.0
        self.busy = False
        self._thread = threading.Thread(target=self._run, daemon=True, name="sitrelax-refit")
        self._thread.start()

    def bump(self) -> int:
        """A newer edit: cancels the fit running now; returns the new generation."""
        with self._cond:
            self.generation += 1
            return self.generation

    def request(self) -> None:
        with self._cond:
            self.generation += 1
            self._wanted = self.generation
            self._cond.notify()

    def outdated(self, generation: int) -> bool:
        return self._closed or self.generation != generation

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def wanted(self) -> bool:
        """A fit is asked for and not yet started."""
        return self._wanted is not None

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._wanted is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
            # wait out the drag's burst and the last fit's own length (what the machine keeps up
            # with), then fit the newest edit
            pause = max(QUIET_S, self._last_start + self._last_seconds - time.perf_counter())
            time.sleep(pause)
            with self._cond:
                generation, self._wanted = self._wanted, None
            if generation is None or self.outdated(generation):
                continue
            self._last_start = time.perf_counter()
            self.busy = True
            try:
                self.session.fit(generation)
            except Exception as exc:  # noqa: BLE001 (the worker lives on; the tabs are told)
                self.session.problem(exc)
            finally:
                self.busy = False
                self._last_seconds = time.perf_counter() - self._last_start

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()


class Judge:
    """Judges the surface of a session's finished fit (`Design.judge`) on a thread of its own,
    once the fit has settled: `request` after a fit is drawn; the newest request wins, and it
    is judged when its delay has passed and no fit runs or is asked for (a drag's refit never
    waits for the check, which is no use to an outdated surface; a check already running when
    a drag starts again shares the machine with its refits), then every view shows the verdict
    (`DesignView.judged`). A fit no longer the session's last is not judged."""

    def __init__(self, session: "Session"):
        self.session = session
        self._cond = threading.Condition()
        self._wanted: tuple[FitOutcome, float] | None = None  # the fit and when it is due
        self._judging = False  # a fit is being judged now
        self._closed = False
        self._thread = threading.Thread(target=self._run, daemon=True, name="sitrelax-judge")
        self._thread.start()

    def request(self, outcome: FitOutcome, delay: float = SETTLE_S) -> None:
        """Judges `outcome` once `delay` seconds have passed with no fit running or asked for
        (at once when it is judged already)."""
        with self._cond:
            self._wanted = (outcome, time.perf_counter() + delay)
            self._cond.notify_all()

    @property
    def pending(self) -> bool:
        """A fit waits to be judged, or is being judged."""
        return self._wanted is not None or self._judging

    def _settled(self) -> bool:
        session = self.session
        return not (session.fit_lock.locked() or session.refitter.busy or
                    session.refitter.wanted)

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._wanted is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                outcome, due = self._wanted
                wait = due - time.perf_counter()
                if outcome.guarantees is None and (wait > 0 or not self._settled()):
                    # (a newer request, or the fit asked for, is seen when the wait ends)
                    self._cond.wait(max(wait, QUIET_S))
                    continue
                self._wanted, self._judging = None, True
            try:
                self._judge(outcome)
            finally:
                with self._cond:
                    self._judging = False
                    self._cond.notify_all()

    def _judge(self, outcome: FitOutcome) -> None:
        session = self.session
        if session.design.last is not outcome:
            return  # a newer fit, or an edit that dropped it: its surface is not on screen
        try:
            session.design.judge(outcome)  # (the fit alone is read: no lock held)
        except Exception as exc:  # noqa: BLE001 (the thread lives on; the tabs are told)
            session.problem(exc, "the check of the surface's guarantees failed")
            return
        with session.lock:
            if session.design.last is outcome:
                for view in list(session.views):
                    view.judged()

    def wait(self, timeout: float) -> bool:
        """Waits until no fit waits to be judged or is being judged (True), or `timeout`
        seconds pass (False)."""
        deadline = time.perf_counter() + timeout
        with self._cond:
            while self.pending and not self._closed:
                left = deadline - time.perf_counter()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class Session:
    """One design session and the views (tabs) showing it: a lock for its edits, the worker
    that refits it, the count of fits drawn and of iterates shown (streamed while fitting)."""

    def __init__(self, db: str | None, name: str = ""):
        self.design = Design(db)
        self.name = name
        self.lock = threading.RLock()
        # one fit at a time: the Fit button's and the refit worker's would both go on from the
        # last fit (or its resume) and race to replace it; the older is cancelled, then waited for
        self.fit_lock = threading.Lock()
        self.views: list["DesignView"] = []
        self.fits = 0
        self.shown = 0
        self.showing_s = 0.0  # the seconds the last fit spent showing its iterates
        self.refitter = Refitter(self)
        self.judge = Judge(self)
        self.stopped = False  # the running fit was cancelled by the Cancel button

    def changed(self, source: "DesignView | None" = None) -> None:
        """Every other view of the session draws the session anew (the source drew its own)."""
        for view in list(self.views):
            if view is not source:
                view.redraw()

    def fit(self, generation: int | None = None, source: "DesignView | None" = None) -> bool:
        """Fits the session now and draws the outcome in every view; False when cancelled.

        A newer edit (`generation` outdated) cancels the fit once it has accepted an iterate
        (or has run `STEP_GRACE_S` without one): the next fit goes on from that iterate, so a
        drag faster than one iteration still moves the surface. Fits run one at a time (the
        Fit button's waits for the worker's it cancelled). The iterates are shown as they
        come, within `SHOW_SHARE` of the fit's time.
        """
        if generation is None:
            generation = self.refitter.bump()
        self.stopped = False
        for view in list(self.views):
            view.fitting(None, None)
        begun, spent, accepted = time.perf_counter(), 0.0, 0

        def progress(iteration: int, energy: float, tau: float) -> None:
            nonlocal accepted
            accepted += 1
            for view in list(self.views):
                view.fitting(iteration, energy)

        def cancel() -> bool:
            stepped = accepted > 0 or time.perf_counter() - begun > STEP_GRACE_S
            return self.refitter.closed or self.stopped or \
                (stepped and self.refitter.outdated(generation))

        def iterate(it: Iterate) -> None:
            nonlocal spent
            if not show_due(spent, time.perf_counter() - begun):
                return
            if not self.lock.acquire(blocking=False):
                return  # the session is being edited or redrawn: the next one, then
            try:
                mesh = self.design.vertices.shape == it.control.shape and \
                    np.array_equal(self.design.faces, it.faces)
                if self.refitter.closed or not mesh:
                    return  # (an iterate outdated by a move is shown: the next fit goes on from it)
                t = time.perf_counter()
                for view in list(self.views):
                    view.show_iterate(it)
                self.shown += 1
                spent += time.perf_counter() - t
            finally:
                self.lock.release()

        with self.fit_lock:  # a fit still running for an older edit was cancelled by `bump`
            if self.refitter.outdated(generation):
                outcome = None  # a newer edit came while it waited: that one's fit follows
            else:
                outcome = self.design.fit(progress, warm=True, iterates=iterate, cancel=cancel)
        self.showing_s = spent
        with self.lock:
            if outcome is None:
                if not self.refitter.wanted:  # no newer fit on its way to take its place
                    for view in list(self.views):
                        view.overtaken()
                return False
            # a finished fit is the session's last (`Design.fit` kept it): it is drawn, even
            # when an edit or a Cancel came in its last moment (a newer fit, if asked, follows)
            self.fits += 1
            for view in list(self.views):
                view.fitted(source)
            # the Fit button's fit is judged at once, a refit once the drag has settled
            self.judge.request(outcome, 0.0 if source is not None else SETTLE_S)
        return True

    def judge_last(self, delay: float = SETTLE_S) -> None:
        """Asks for the last fit to be judged (after an undo, a relief), if it is not yet."""
        last = self.design.last
        if last is not None and last.guarantees is None:
            self.judge.request(last, delay)

    def cancel_fit(self) -> None:
        """Stops the running fit at its next iteration (the surface drawn stays the last
        finished fit's); called without the session's lock, which a running fit may hold."""
        self.stopped = True
        self.refitter.bump()

    def problem(self, exc: Exception, what: str = "the refit failed") -> None:
        """A refit (or `what` else) failed (a person out of reach, ...): every view says so,
        in its status line (the next action clears it) and as a notice."""
        bad_input = isinstance(exc, (ValueError, OSError, KeyError))
        text = f"{what}: {exc}" if bad_input else f"{what}: {type(exc).__name__}: {exc}"
        for view in list(self.views):
            view.progress.content = ""
            view._status(f"{PROBLEM if bad_input else INTERNAL} {text}")
            notice(view.client, "Problem" if bad_input else "Internal error", text)

    def close(self) -> None:
        self.refitter.close()
        self.judge.close()


class DesignView:
    """The Design tab of one browser tab (`studio.context.View`)."""

    prefix = "/design"

    def __init__(self, client, tab, context: StudioContext):
        self.client = client
        self.scene = client.scene
        self.context = context
        self.out = Path(context.out)
        # the view's nodes hang under one frame, which the studio hides with its tab (the
        # 3D view's clicks are then another view's: they pick nothing here)
        self.root = self.scene.add_frame(self.prefix, show_axes=False)
        self.session = Session(context.db)
        self.session.views.append(self)
        self.selection: list[int] = []
        self.status_text = ""
        self._syncing = False  # the view is setting its own inputs: not an edit
        self._people: list = []  # per person: its gizmo
        self._bodies: list = []
        self._relaxed: dict[int, object] = {}
        self._surface = None
        self._fitted_net = None
        self._drawn_fit = None  # the fit outcome the surface drawn is of (None: an iterate)
        self._drawn_quads: tuple = (None, None)  # the quads of the surface and of the net drawn
        self._fit_news = ""  # the running fit's last iteration and energy
        self._shown_iteration: int | None = None  # the running fit's iterate drawn last
        self._gizmo = None
        self._gizmo_start: tuple[np.ndarray, np.ndarray] | None = None
        self._leaving: str | None = None  # the session a join was warned about (pressed again)
        self._unread: Exception | None = None  # why the library could not be read at the start
        self._saved: set = set()  # the files and scenarios this tab saved (saved again freely)
        self._shown_start = None  # the session's start the panel shows (`_show_start`)
        self._replacing = None  # the one a save was warned about (pressed again: replaced)
        with tab:
            self._build_gui()
        self._wire()
        self.scene.on_click()(lambda e: self._guarded(lambda: self._clicked(e, add=False)))
        self.scene.on_click(modifier="shift")(
            lambda e: self._guarded(lambda: self._clicked(e, add=True)))
        self.scene.on_rect_select(modifier="shift")(
            lambda e: self._guarded(lambda: self._boxed(e)))
        self.redraw()
        self._status("Add people (a seated pose is chosen), then press **Fit**, or drag with "
                     "**Refit while dragging** on." if self._unread is None else
                     f"{PROBLEM} the pose library cannot be read ({self._unread}): its poses "
                     f"are listed once it can be; the bundled recordings are.")
        # the pose list follows the library (renames, recordings)
        self._watch = LibraryWatch(context.db, self._relist, "design-poll") \
            if context.db is not None else None

    def _relist(self) -> None:
        """Lists the poses again, keeping the pose chosen while it is still there."""
        options = self._pose_options(self.tags.value)
        with self.session.lock:
            chosen = self.pose.value
            self.pose.options = options
            self.pose.value = chosen if chosen in options else self._default(options)

    @property
    def design(self) -> Design:
        return self.session.design

    @property
    def fits(self) -> int:
        return self.session.fits

    # GUI ----------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.client.gui
        with gui.add_folder("Run"):
            self.fit = gui.add_button("Fit")
            self.cancel = gui.add_button("Cancel fit")
            self.relieve = gui.add_button(
                "Relieve pressure", hint="Rounds of pressure relief after the fit on screen "
                "(README, 'Pressure relief'): eased where the bodies press hardest, refitted, "
                "kept only if no bar met is missed; seconds a round")
            self.live = gui.add_checkbox("Refit while dragging", initial_value=True)
            self.undo = gui.add_button("Undo", disabled=True)
            self.redo = gui.add_button("Redo", disabled=True)
            self.status = gui.add_markdown("")
            self.warnings = gui.add_markdown("")
            self.progress = gui.add_markdown("")
        with gui.add_folder("People"):
            self.tags = gui.add_text("Tags", initial_value="",
                                     hint="a tag expression, e.g. sit and not high")
            self.search = gui.add_button("Search library")
            try:
                options = self._pose_options("")
            except (ValueError, OSError) as exc:  # (a library unreadable: said once built)
                self._unread = exc
                options = self._pose_options("", library=False)
            self.pose = gui.add_dropdown("Pose", options, initial_value=self._default(options))
            self.frame = gui.add_number("Frame (recordings)", initial_value=39, min=0, step=1)
            self.add = gui.add_button("Add person")
            self.selected = gui.add_dropdown("Selected", ["(none)"])
            self.position = gui.add_vector3("Position (m)", initial_value=(0.0, 0.0, 0.0),
                                            step=0.01)
            self.rotation = gui.add_vector3("Rotation (deg)", initial_value=(0.0, 0.0, 0.0),
                                            step=1.0)
            self.shape = {key: gui.add_slider(key.capitalize(), min=0.0, max=1.0, step=0.05,
                                              initial_value=getattr(BodyShape(), key))
                          for key in SHAPE_KEYS}
            support = support_regions(schema.default(schema.Person, "support"))
            self.parts = {region: gui.add_checkbox(f"Support {region.replace('_', ' ')}",
                                                   initial_value=region in support)
                          for region in BODY_REGIONS}
            self.apply = gui.add_button("Apply shape and support")
            self.relax = gui.add_button("Relax selected person")
            self.save_pose = gui.add_button("Save relaxed pose to library")
            self.remove = gui.add_button("Remove person")
            self.bodies = gui.add_dropdown("Bodies", tuple(BODY_MODES), initial_value="shown")
        grid, params = schema.Grid(), self.design.params  # the schema's defaults
        with gui.add_folder("Control mesh"):
            self.picked = gui.add_text("Picked vertices", initial_value="",
                                       hint="click a vertex (shift: add, shift-drag: box) or "
                                            "type indices")
            self.centroid = gui.add_vector3("Picked at (m)", initial_value=(0.0, 0.0, 0.0),
                                            step=0.01)
            self.fix = gui.add_button("Fix picked")
            self.free = gui.add_button("Free picked")
            self.crease = gui.add_button("Crease picked edges")
            self.smooth = gui.add_button("Smooth picked edges")
            self.split = gui.add_button("Split picked face")
            self.clear = gui.add_button("Clear picks")
            self.grid_size = gui.add_vector2("Grid size (m)", initial_value=tuple(grid.size),
                                             min=(0.05, 0.05), max=(10.0, 10.0), step=0.05)
            self.grid_res = gui.add_vector2("Grid faces", initial_value=tuple(grid.resolution),
                                            min=(1, 1), max=(40, 40), step=1)
            self.grid_height = gui.add_number("Grid height (m)", initial_value=grid.height,
                                              min=-5.0, max=5.0, step=0.01)
            self.new_grid = gui.add_button("New grid")
            self.template = gui.add_dropdown("Template", tuple(TEMPLATES),
                                             initial_value="chair")
            self.build = gui.add_button("Build template around people",
                                        hint="every dimension measured on the people as "
                                             "they are placed; each supported as its use")
            self.upload = gui.add_upload_button("Load control mesh (OBJ)", mime_type=".obj")
            self.level = gui.add_slider("Level", min=1, max=3, step=1,
                                        initial_value=params["level"])
            # (typed as text: a number input drops the exponent of 3e-3 and clamps silently)
            self.sigma = gui.add_text("Sigma", initial_value=f"{params['sigma']:g}",
                                      hint="smoothness weight, e.g. 0.003 or 3e-3 (0-100)")
            self.tau = gui.add_slider("Tau max", min=0.0, max=1.0, step=0.05,
                                      initial_value=params["tau_max"])
            self.margin = gui.add_slider("Margin (m)", min=0.0, max=0.1, step=0.005,
                                         initial_value=params["margin"])
            self.adopt = gui.add_button("Start from the fitted mesh")
        with gui.add_folder("Session and files"):
            self.join_name = gui.add_text("Session", initial_value="",
                                          hint="empty: this tab's own; a name: shared by the "
                                               "tabs that join it")
            self.join = gui.add_button("Join session")
            self.name = gui.add_text("Name", initial_value="studio-design")
            self.open = gui.add_upload_button(
                "Open scenario (TOML)", mime_type=".toml",
                hint="a scenario file (Save TOML's, sitrelax design's): its people, surface "
                     "and parameters replace the session's (one step: Undo brings it back)")
            self.save_db = gui.add_button("Save to library")
            self.save_toml = gui.add_button("Save TOML")
            self.export = gui.add_button("Export (zip)")

    def _wire(self) -> None:
        actions = [
            (self.search, lambda: self._set_options(self._pose_options(self.tags.value))),
            (self.add, self._add_person), (self.apply, self._apply_person),
            (self.remove, self._remove_person), (self.relax, self._relax),
            (self.save_pose, self._save_pose), (self.new_grid, self._new_grid),
            (self.build, self._build_template),
            (self.adopt, self._adopt), (self.fit, self.run_fit), (self.undo, self._undo),
            (self.relieve, self._relieve),
            (self.redo, self._redo), (self.fix, lambda: self._fix(True)),
            (self.free, lambda: self._fix(False)), (self.crease, lambda: self._crease(True)),
            (self.smooth, lambda: self._crease(False)), (self.split, self._split),
            (self.clear, lambda: self.pick([])), (self.join, self._join),
            (self.save_db, self._save_db), (self.save_toml, self._save_toml),
            (self.export, self._export),
        ]
        for button, action in actions:
            button.on_click(lambda _event, action=action: self._guarded(action))
        inputs = [(self.selected, self._show_person), (self.position, self._typed_person),
                  (self.rotation, self._typed_person), (self.picked, self._typed_picks),
                  (self.centroid, self._typed_centroid), (self.bodies, self._draw_bodies_mode)]
        for handle, action in inputs:
            handle.on_update(lambda _e, action=action: None if self._syncing else
                             self._guarded(action))
        self.sigma.on_update(lambda _e: None if self._syncing else
                             self._guarded(self._typed_sigma))
        for name, handle in (("level", self.level), ("tau_max", self.tau),
                             ("margin", self.margin)):
            handle.on_update(lambda _e, name=name, handle=handle: None if self._syncing else
                             self._guarded(lambda: self._set_parameter(name, handle.value)))
        self.upload.on_upload(lambda _e: self._guarded(self._load_mesh))
        self.open.on_upload(lambda _e: self._guarded(self._open_scenario))
        # (not guarded: the Fit button's fit holds the session's lock while it runs)
        self.cancel.on_click(lambda _e: self._cancel())

    def _guarded(self, action) -> None:
        """Runs one action at a time in the session; a problem becomes the status line."""
        guarded(self.session.lock, action, self._status, self.client, self.status_text)

    def _status(self, text: str) -> None:
        self.status_text = text
        self.status.content = text

    def _set(self, handle, value) -> None:
        """Shows a value in an input without taking it as an edit."""
        self._syncing = True
        try:
            handle.value = value
        finally:
            self._syncing = False

    def _edited(self, refit: bool = False) -> None:
        """After an edit: the other views of the session redraw, the history buttons follow,
        and (refit, with live refitting on) the worker fits the new state."""
        self.session.changed(self)
        self._history_buttons()
        self._show_warnings()
        if refit and self.live.value and self.design.people:
            self.session.refitter.request()
        else:
            self.session.refitter.bump()  # a fit of the old state is no use now

    def _history_buttons(self) -> None:
        self.undo.disabled = not self.design.can_undo
        self.redo.disabled = not self.design.can_redo

    # people ---------------------------------------------------------------------------------
    def _pose_options(self, expr: str, library: bool = True) -> list[str]:
        from capture.recordings import bundled_recordings

        names: list[str] = []
        if self.design.db is not None and library:
            from posedb import PoseLibrary

            names = PoseLibrary(self.design.db).search_poses(expr.strip() or None)
        return names + [f"recording: {r}" for r in bundled_recordings()] or ["(none)"]

    @staticmethod
    def _default(options: list[str]) -> str:
        """The seated recording `DEFAULT_POSE` names (frame 39 is the frame field's start)."""
        seated = "recording: " + DEFAULT_POSE.split(":", 2)[2].split("#")[0]
        return seated if seated in options else options[0]

    def _set_options(self, options: list[str]) -> None:
        self.pose.options = options
        self.pose.value = options[0]
        found = sum(not o.startswith("recording: ") for o in options)
        self._status(f"{found} library pose(s) match.")

    def _pose_spec(self) -> str:
        choice = self.pose.value
        if choice.startswith("recording: "):
            return f"bvh:bundled:{choice[len('recording: '):]}#frame={int(self.frame.value)}"
        return f"db:{choice}"

    def add_person(self, pose: str, **fields) -> int:
        """Adds a person (what the Add button does with the chosen pose)."""
        k = self.design.add_person(pose, **fields)
        self.redraw()
        self._set(self.selected, self._labels()[k])
        self._show_person()
        self._edited()
        self._status(f"Added {self.design.people[k]['name']} ({pose}).")
        return k

    def _add_person(self) -> None:
        self.add_person(self._pose_spec())

    def _labels(self) -> list[str]:
        """The Selected list's entries: number, name and pose, short enough for the panel
        (a bundled recording by its name and frame: `cmu_75_18_high_sit #39`)."""
        return [f"{k + 1}: {p['name']} ({_short_pose(p['pose'])})"
                for k, p in enumerate(self.design.people)]

    def selected_person(self) -> int:
        labels = self._labels()
        if self.selected.value not in labels:
            raise DesignError("Select a person first")
        return labels.index(self.selected.value)

    def _show_person(self) -> None:
        if self.selected.value not in self._labels():
            return
        p = self.design.people[self.selected_person()]
        body = p.get("body", {})
        for key, slider in self.shape.items():
            self._set(slider, float(body.get(key, getattr(BodyShape(), key))))
        support = support_regions(p["support"])  # a use or coarse part as its regions
        for region, box in self.parts.items():
            self._set(box, region in support)
        self._set(self.position, tuple(float(c) for c in p["position"]))
        self._set(self.rotation, tuple(float(c) for c in p["rotation_deg"]))

    def _apply_person(self) -> None:
        k = self.selected_person()
        support = [part for part, box in self.parts.items() if box.value]
        body = {key: float(s.value) for key, s in self.shape.items()}
        try:
            self.design.update_person(k, body=body, support=support)
        except ValueError:
            self._show_person()  # the panel shows what the person keeps
            raise
        self.redraw()
        self._edited()
        self._status(f"{self.design.people[k]['name']}: shape and support set.")

    def _typed_person(self) -> None:
        k = self.selected_person()
        position = [round(float(c), 4) for c in self.position.value]
        rotation = [round(float(c), 3) for c in self.rotation.value]
        try:
            self.design.update_person(k, position=position, rotation_deg=rotation)
        except ValueError:
            self._show_person()  # the fields show where the person stays
            raise
        gizmo = self._people[k]
        gizmo.position, gizmo.wxyz = tuple(position), tuple(quat_wxyz(rotation))
        self._draw_relaxed()
        self._edited(refit=True)
        self._status(f"{self.design.people[k]['name']} at {position} m, turned {rotation} deg.")

    def _remove_person(self) -> None:
        k = self.selected_person()
        name = self.design.people[k]["name"]
        self.design.remove_person(k)
        self.redraw()
        self._edited()
        self._status(f"Removed {name}.")

    def _moved(self, k: int, gizmo, phase: str) -> None:
        if k >= len(self.design.people):
            return
        if phase == "start":
            self.design.end_group()
        position = [round(float(c), 4) for c in gizmo.position]
        rotation = self.design.people[k]["rotation_deg"]
        if not same_turn(gizmo.wxyz, rotation):  # (a move keeps the rotation as typed)
            rotation = euler_deg(gizmo.wxyz)
        self.design.update_person(k, group=f"move person {k}", position=position,
                                  rotation_deg=rotation)
        if phase == "end":
            self.design.end_group()
        if self.selected.value in self._labels() and self.selected_person() == k:
            self._set(self.position, tuple(position))
            self._set(self.rotation, tuple(self.design.people[k]["rotation_deg"]))
        self._draw_relaxed()
        self._edited(refit=True)
        if phase == "end":
            self._status(f"{self.design.people[k]['name']} at {position} m, turned "
                         f"{list(self.design.people[k]['rotation_deg'])} deg.")

    def _draw_bodies_mode(self) -> None:
        self._draw_people(self._pressure())

    def _pressure(self):
        last = self.design.last
        if last is None or len(last.pressure) != len(self.design.people):
            return None
        return last.pressure

    def _draw_people(self, pressure=None) -> None:
        """Each person's gizmo where the person is, and its body (coloured by `pressure` when
        given); a body already drawn as it should be is not sent again (a body is 13k
        vertices, and a slow browser would fall behind)."""
        people = self.design.people
        while len(self._people) > len(people):
            self._people.pop().remove()
            self._bodies.pop()
        opacity = BODY_MODES[self.bodies.value]
        peak = 1.0
        if pressure is not None:
            peak = max((float(p.max()) for p in pressure), default=1.0) or 1.0
        for k, person in enumerate(people):
            if k == len(self._people):
                gizmo = self.scene.add_transform_controls(
                    f"{self.prefix}/people/p{k}", scale=0.35,
                    position=tuple(person["position"]),
                    wxyz=tuple(quat_wxyz(person["rotation_deg"])))
                gizmo.on_update(lambda e, k=k, gizmo=gizmo: self._guarded(
                    lambda: self._moved(k, gizmo, e.phase)))
                self._people.append(gizmo)
                self._bodies.append((None, None))
            gizmo = self._people[k]
            gizmo.position = tuple(person["position"])
            gizmo.wxyz = tuple(quat_wxyz(person["rotation_deg"]))
            origin = dict(person, position=[0.0, 0.0, 0.0], rotation_deg=[0.0, 0.0, 0.0])
            shade = None if pressure is None else (id(pressure[k]), peak)
            key = (json.dumps(origin, sort_keys=True), shade, opacity)
            if self._bodies[k][1] == key:
                continue
            local = self.design.place(origin)
            name = f"{self.prefix}/people/p{k}/body"
            if pressure is not None and opacity == 1.0:
                body = self._colored_mesh(name, local.vertices, local.body.triangles,
                                          pressure_on_skin(pressure[k], peak))
            else:  # a ghost is one see-through colour (viser draws coloured meshes opaque)
                body = self.scene.add_mesh_simple(name, local.vertices, local.body.triangles,
                                                  color=_rgb(SKIN), opacity=opacity)
            body.visible = opacity > 0
            self._bodies[k] = (body, key)

    def _colored_mesh(self, name: str, vertices, triangles, colors):
        import trimesh

        mesh = trimesh.Trimesh(vertices, triangles, process=False)
        rgba = np.concatenate([np.asarray(colors), np.ones((len(colors), 1))], axis=1)
        mesh.visual.vertex_colors = (rgba * 255).astype(np.uint8)
        return self.scene.add_mesh_trimesh(name, mesh)

    def _relax(self) -> None:
        k = self.selected_person()
        res = self.design.relax(k)
        self._draw_relaxed()
        self._edited()
        self._status(f"Relaxed {self.design.people[k]['name']} in {res.seconds:.2f} s: mean "
                     f"support distance {100 * res.before['mean_support_distance_m']:.1f} -> "
                     f"{100 * res.after['mean_support_distance_m']:.1f} cm (green); "
                     f"{res.summary}.")

    def _draw_relaxed(self) -> None:
        for k in list(self._relaxed):
            if k not in self.design.relaxed:
                self._relaxed.pop(k)[0].remove()
        for k, res in self.design.relaxed.items():
            if k in self._relaxed and self._relaxed[k][1] is res:
                continue
            if k in self._relaxed:
                self._relaxed.pop(k)[0].remove()
            handle = self.scene.add_mesh_simple(f"{self.prefix}/relaxed/p{k}", res.vertices,
                                                res.faces, color=RELAXED_COLOR, opacity=0.8)
            self._relaxed[k] = (handle, res)

    def _save_pose(self) -> None:
        k = self.selected_person()
        with self.context.library_lock:
            saved = self.design.save_relaxed(k)
        kept = "" if self.design.relaxed[k].result.accepted else \
            " (the relaxation kept the captured pose)"
        self._status(f"Saved {self.design.people[k]['name']}'s relaxed pose as "
                     f"{saved['name']!r} ({saved['id']}) in {self.design.db}{kept}.")

    # the control mesh -------------------------------------------------------------------
    def pick(self, indices, add: bool = False) -> None:
        """Picks control vertices (add: toggles them in the picks instead)."""
        js = [int(j) for j in indices]
        for j in js:
            if not 0 <= j < len(self.design.vertices):
                last = len(self.design.vertices) - 1
                raise DesignError(f"Expected control vertices in 0..{last}, got {j}")
        if add:
            chosen = list(self.selection)
            for j in js:
                if j in chosen:
                    chosen.remove(j)
                else:
                    chosen.append(j)
            js = chosen
        self.selection = list(dict.fromkeys(js))
        self._set(self.picked, " ".join(str(j) for j in self.selection))
        self._draw_control()

    def _typed_picks(self) -> None:
        text = self.picked.value.replace(",", " ").split()
        try:
            js = [int(t) for t in text]
        except ValueError:
            raise DesignError(f"Expected vertex indices separated by spaces, got "
                              f"{self.picked.value[:80]!r}") from None
        self.pick(js)

    def _clicked(self, event, add: bool) -> None:
        if not self.root.visible:
            return
        j = ray_pick(self.design.vertices, event.ray_origin, event.ray_direction)
        if j is None:
            if not add:
                self.pick([])
            return
        self.pick([j], add=add)
        self._status(f"Picked control vertex {j}" + (f" ({len(self.selection)} picked)."
                                                    if len(self.selection) > 1 else "."))

    def _boxed(self, event) -> None:
        if not self.root.visible:
            return
        camera = event.client.camera
        uv, front = project(self.design.vertices, camera.position, camera.wxyz, camera.fov,
                            camera.aspect)
        lo, hi = np.asarray(event.screen_min), np.asarray(event.screen_max)
        inside = front & np.all((uv >= lo) & (uv <= hi), axis=1)
        fresh = [int(j) for j in np.flatnonzero(inside) if j not in self.selection]
        self.pick(self.selection + fresh)
        self._status(f"Box picked {len(fresh)} more vertices ({len(self.selection)} picked).")

    def _picked(self) -> list[int]:
        if not self.selection:
            raise DesignError("Pick control vertices first (click them, or type their indices)")
        return self.selection

    def _fix(self, fixed: bool) -> None:
        js = self._picked()
        self.design.set_fixed(js, fixed)
        self._draw_control()
        self._edited()
        self._status(f"{'Fixed' if fixed else 'Freed'} {len(js)} control vertices.")

    def _crease(self, sharp: bool) -> None:
        picked = set(self._picked())
        edges = [tuple(e) for e in self.design.control_edges().tolist()
                 if e[0] in picked and e[1] in picked]
        if not edges:
            raise DesignError("Pick two vertices that share a control edge (or more) for a "
                              "crease")
        with self.design.edit():
            for i, j in edges:
                self.design.set_crease(i, j, sharp)
        self._draw_control()
        self._edited()
        self._status(f"{'Creased' if sharp else 'Smoothed'} {len(edges)} control edge(s).")

    def _split(self) -> None:
        face = self.design.face_of(self._picked())
        new = self.design.split_face(face)
        self.selection = []
        self._clear_surface()
        self.pick([])
        self._edited()
        self._status(f"Split control face {face}: {len(new)} new vertices, "
                     f"{len(self.design.faces)} faces now.")

    def _typed_centroid(self) -> None:
        js = self._picked()
        v = self.design.vertices[js]
        target = np.asarray(self.centroid.value, dtype=np.float64)
        try:
            self.design.move_vertices(js, v + (target - v.mean(axis=0)))
        except ValueError:
            self._draw_control()  # the field shows where the picks stay
            raise
        self._draw_control()
        self._edited(refit=True)
        self._status(f"Moved {len(js)} vertices' centroid to {np.round(target, 4).tolist()} m.")

    def _gizmo_moved(self, gizmo, phase: str) -> None:
        if not self.selection:
            return
        if phase == "start" or self._gizmo_start is None:
            self.design.end_group()
            js = list(self.selection)
            self._gizmo_start = (self.design.vertices[js].copy(),
                                 np.asarray(gizmo.position, dtype=np.float64).copy())
        start, at = self._gizmo_start
        if len(start) != len(self.selection):
            return
        delta = np.asarray(gizmo.position, dtype=np.float64) - at
        self.design.move_vertices(self.selection, start + delta, group="drag vertices")
        if phase == "end":
            self.design.end_group()
            self._gizmo_start = None
        self._draw_control(keep_gizmo=True)
        self._edited(refit=True)

    def _draw_control(self, keep_gizmo: bool = False) -> None:
        v = self.design.vertices
        edges = self.design.control_edges()
        self.scene.add_line_segments(f"{self.prefix}/control/edges", v[edges], CONTROL_COLOR,
                                     thickness=2.0, thickness_units="screen")
        creases = np.array(sorted(self.design.creases), dtype=np.int64).reshape(-1, 2)
        if len(creases):
            self.scene.add_line_segments(f"{self.prefix}/control/creases", v[creases],
                                         CREASE_COLOR, thickness=6.0, thickness_units="screen")
        else:
            self.scene.remove_by_name(f"{self.prefix}/control/creases")
        colors = np.array([SELECTED_COLOR if j in self.selection else
                           FIXED_COLOR if j in self.design.fixed else FREE_COLOR
                           for j in range(len(v))], dtype=np.uint8)
        self.scene.add_point_cloud(f"{self.prefix}/control/vertices", v, colors,
                                   point_size=0.013, point_shape="circle")
        if self.selection:
            self._set(self.centroid, tuple(float(c) for c in v[self.selection].mean(axis=0)))
        if keep_gizmo:
            return
        if self._gizmo is not None:
            self._gizmo.remove()
            self._gizmo = None
        self._gizmo_start = None
        if self.selection:
            self._gizmo = self.scene.add_transform_controls(
                f"{self.prefix}/control/handle", scale=0.12, disable_rotations=True,
                position=tuple(v[self.selection].mean(axis=0)), depth_test=False)
            gizmo = self._gizmo
            gizmo.on_update(lambda e: self._guarded(lambda: self._gizmo_moved(gizmo, e.phase)))

    def _new_grid(self) -> None:
        size = tuple(float(c) for c in self.grid_size.value)
        res = tuple(int(round(c)) for c in self.grid_res.value)
        self.design.new_grid(size, res, float(self.grid_height.value))
        self.selection = []
        self.redraw()
        self._edited()
        self._status(f"New {res[0]} x {res[1]} grid, {size[0]:g} x {size[1]:g} m.")

    def _build_template(self) -> None:
        name = self.template.value
        use = self.design.build_template(name)
        self.selection = []
        self.redraw()
        self._edited()
        self._status(f"A {name} built around the people "
                     f"({len(self.design.vertices)} control vertices, "
                     f"{len(self.design.creases)} crease edges); each person is supported as "
                     f"`{use}` ({', '.join(support_regions(use))}).")

    def _load_mesh(self) -> None:
        import tempfile

        upload = self.upload.value
        if len(upload.content) > self.context.limit:
            raise DesignError(f"{upload.name} is {len(upload.content)} bytes; the studio takes "
                              f"control meshes up to {self.context.limit} bytes")
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / Path(upload.name).name
            path.write_bytes(upload.content)
            self.design.load_control_mesh(path)
        self.selection = []
        self.redraw()
        self._edited()
        self._status(f"Loaded {upload.name}: {len(self.design.vertices)} control vertices.")

    def _open_scenario(self) -> None:
        """The uploaded scenario file replaces the session (`Design.open_scenario`); its name
        becomes the Name that Save TOML and the exports use."""
        upload = self.open.value
        if len(upload.content) > self.context.limit:
            raise DesignError(f"{upload.name} is {len(upload.content)} bytes; the studio takes "
                              f"scenario files up to {self.context.limit} bytes")
        opened = self.design.open_scenario(upload.content, upload.name)
        self.selection = []
        stem = Path(upload.name).stem
        try:
            self._set(self.name, check_name(stem))
        except DesignError:
            pass  # (a file name that is no design name: the Name stays)
        self.redraw()
        self._edited()
        people = len(self.design.people)
        self._status(f"Opened {upload.name}: {people} {'person' if people == 1 else 'people'} "
                     f"on {opened.surface.source} ({len(self.design.vertices)} control "
                     f"vertices).")

    def _set_parameter(self, name: str, value) -> None:
        try:
            self.design.set_parameter(name, value)
        except ValueError:
            self._show_parameters()  # the panel shows the value the session keeps
            raise
        self._edited()

    def _show_parameters(self) -> None:
        """The panel's parameters as the session holds them (after an undo, a join, another
        tab's edit)."""
        params = self.design.params
        for handle, value in ((self.level, params["level"]), (self.tau, params["tau_max"]),
                              (self.margin, params["margin"])):
            if handle.value != value:
                self._set(handle, value)
        if self.sigma.value.strip() != f"{params['sigma']:g}":
            self._set(self.sigma, f"{params['sigma']:g}")

    def _typed_sigma(self) -> None:
        """Sigma as typed: a number from 0 to 100 (3e-3 as well as 0.003); anything else is
        refused, and the field shows the value kept."""
        text = self.sigma.value.strip()
        kept = self.design.params["sigma"]
        try:
            value = float(text)
        except ValueError:
            if _PARTIAL_NUMBER.fullmatch(text):
                return  # a number being typed, key by key ("", "-", "3e", "3e-"): wait
            value = None
        if value is None or not 0.0 <= value <= 100.0:
            self._set(self.sigma, f"{kept:g}")
            raise DesignError(f"Expected sigma as a number from 0 to 100 (e.g. 0.003 or 3e-3), "
                              f"got {text[:40]!r}; it stays {kept:g}") from None
        if value != kept:
            self._set_parameter("sigma", value)
            self._status(f"Sigma is {value:g}.")

    def _adopt(self) -> None:
        self.design.adopt_fit()
        self.redraw()
        self._edited()
        self._status("The fitted control mesh is the start now.")

    # history --------------------------------------------------------------------------------
    def _undo(self) -> None:
        self.design.undo()
        self._after_history("Undone")

    def _redo(self) -> None:
        self.design.redo()
        self._after_history("Redone")

    def _after_history(self, what: str) -> None:
        self.selection = [j for j in self.selection if j < len(self.design.vertices)]
        self.redraw()
        self._edited()
        self.session.judge_last()  # (a fit back on screen that was never judged)
        self._status(f"{what}." + (f"\n\n{self._figures()}" if self.design.last else ""))

    # fitting ------------------------------------------------------------------------------
    def run_fit(self) -> None:
        """Fits the session now and draws it (the Fit button)."""
        self._status("Fitting...")
        if not self.design.people:
            raise DesignError("Add a person first: the scene is empty")
        if not self.session.fit(source=self):
            self._status("The fit was cancelled: the surface shown is the last finished fit's."
                         if self.session.stopped else "The fit was overtaken by a newer edit.")

    def _cancel(self) -> None:
        """The Cancel fit button: stops the running fit (or the refit asked for)."""
        session = self.session
        if not (session.fit_lock.locked() or session.refitter.busy or session.refitter.wanted):
            self._status("No fit is running: nothing to cancel.")
            return
        session.cancel_fit()

    def _relieve(self) -> None:
        """Rounds of pressure relief after the fit on screen (the Relieve pressure button)."""
        self._status("Relieving pressure...")

        def say(line: str) -> None:
            self.progress.content = f"*{line[0].upper()}{line[1:]}*"

        record = self.design.relieve(say=say)
        self.fitted()
        self.session.judge_last(0.0)  # (a kept fit relief checked is judged already)
        line = relief_text(record)
        if line is None:  # a peak set against a flat seat's is what relief lowers
            measured = [p for p in self.design.last.persons if p.get("peak_of_flat") is not None
                        and p.get("posture") not in NO_SEAT_POSTURES]
            line = ("no round ran: every peak is at the aim already (half the flat seat's)"
                    if measured else "no round ran: no seated body rests on the surface, so "
                    "no peak is set against a flat seat's to lower")
        self._status(f"{line[0].upper()}{line[1:]}.\n\n{self._figures()}")
        self._show_warnings()

    def fitting(self, iteration: int | None, energy: float | None) -> None:
        """A fit's news: started (None) or one more accepted iteration."""
        if iteration is None:
            self._fit_news, self._shown_iteration = "Fitting...", None
        else:
            self._fit_news = f"Fitting: iteration {iteration}, energy {energy:.4g}"
        self._show_progress()

    def show_iterate(self, it: Iterate) -> None:
        """Shows an iterate of the running fit: its level-s surface and its control net, their
        vertices sent alone while the quads are those drawn."""
        self._show_surface(it.surface, it.surface_faces, it.control, it.faces)
        self._drawn_fit = None  # a redraw draws the last finished fit again
        self._shown_iteration = it.iteration
        self._show_progress()  # after the surface: a page that shows this has the surface

    def overtaken(self) -> None:
        """The running fit was cancelled and no other follows: the last finished fit again."""
        self._fit_news, self._shown_iteration = "", None
        self.progress.content = "*Fit cancelled.*" if self.session.stopped else ""
        self._draw_surface()

    def _show_progress(self) -> None:
        shown = "" if self._shown_iteration is None else \
            f"; surface of iteration {self._shown_iteration} shown"
        self.progress.content = f"*{self._fit_news}{shown}*"

    def fitted(self, source: "DesignView | None" = None) -> None:
        """Draws the last fit: surface, fitted control net, bodies by pressure, figures and
        what misses the bars."""
        outcome = self.design.last
        if outcome is None:
            return
        self.progress.content = ""
        self._shown_iteration = None
        self._draw_surface()
        self._draw_people(self._pressure())
        self._draw_relaxed()
        r = outcome.result
        self._status(f"**Fitted** (fit {self.session.fits}) in {r.iterations} iterations, "
                     f"{outcome.seconds:.2f} s ({r.stop_reason.split(':')[0]}).\n\n"
                     f"{self._figures()}")
        self._show_warnings()

    def _figures(self) -> str:
        """The last fit's figures per person, as a markdown table."""
        rows = "\n".join(
            f"| {p['name'].split(' (')[0]} | {p['coverage']:.2f} | "
            # (a body at no rest: why is among the warnings, once)
            f"{'no rest' if p.get('supported') is False else f'{peak_text(p)} / {flat_text(p)}'}"
            f" | {1000 * p['max_penetration_m']:.0f} |" for p in self.design.last.persons)
        return ("| person | coverage | peak kPa (flat) | into skin mm |\n|---|---|---|---|\n"
                f"{rows}")

    def _draw_surface(self) -> None:
        outcome = self.design.last
        if outcome is None:
            self._clear_surface()
            return
        if self._surface is not None and self._drawn_fit is outcome:
            return
        self._drawn_fit = outcome
        r = outcome.result
        # the limit surface (what is exported and judged) on the iterates' level-s quads
        self._show_surface(r.surface if outcome.limit is None else outcome.limit,
                           r.surface_faces, r.control, r.faces)

    def _show_surface(self, surface: np.ndarray, surface_faces: np.ndarray,
                      control: np.ndarray, faces: np.ndarray) -> None:
        """The surface node (vertices (ns, 3) m, quads (Fs, 4)) and the fitted control net
        (control vertices (n0, 3) m, quads (F0, 4)): where the quads are those drawn, only the
        new vertices are sent."""
        drawn_surface, drawn_net = self._drawn_quads
        if self._surface is not None and np.array_equal(drawn_surface, surface_faces):
            self._surface.vertices = surface
        else:
            self._surface = self.scene.add_mesh_simple(
                f"{self.prefix}/surface", surface, quad_triangles(surface_faces),
                color=_rgb(SURFACE), side="double")
        edges = control_edges(faces)
        if self._fitted_net is not None and np.array_equal(drawn_net, faces):
            self._fitted_net.points = control[edges]
        else:
            self._fitted_net = self.scene.add_line_segments(
                f"{self.prefix}/fitted_net", control[edges], FITTED_NET_COLOR, thickness=1.5,
                thickness_units="screen")
        self._drawn_quads = (surface_faces, faces)

    def _clear_surface(self) -> None:
        for name in ("_surface", "_fitted_net"):
            handle = getattr(self, name)
            if handle is not None:
                handle.remove()
                setattr(self, name, None)
        self._drawn_fit, self._drawn_quads = None, (None, None)

    def _show_warnings(self) -> None:
        """What the poses and the fit on screen miss (its surface's guarantees once judged,
        then each person's bars), and whether its surface meets its guarantees."""
        lines = self.design.pose_warnings() + self.design.result_warnings()
        shown = [f"<span style='color:#c0392b'>&#9888; {line}</span>  " for line in lines]
        verdict = self._verdict()
        self.warnings.content = "\n".join(shown + ([verdict] if verdict else []))
        self.warning_lines = lines

    def _verdict(self) -> str:
        """One line: whether the surface on screen meets its guarantees (the export's: no
        self-crossing, no fold, no slit, above the floor, no cut past the margin), not yet
        judged, or what it misses (listed above, in report.json's words); '' with no fit."""
        last = self.design.last
        if last is None:
            return ""
        g = last.guarantees
        if g is None:
            return ("*The surface's guarantees (no self-crossing, no fold, no slit, above the "
                    "floor, no cut past the margin) are checked once the fit settles...*")
        took = "" if last.judge_seconds is None else f"; checked in {last.judge_seconds:.2f} s"
        misses = self.design.surface_warnings()
        if misses:
            return (f"*The surface misses {len(misses)} of its guarantees, as the export's "
                    f"report.json will say (above){took}.*")
        floor = "" if g["floor_m"] is None else ", above the floor"
        return (f"<span style='color:#1e8449'>&#10003; The surface meets its guarantees: no "
                f"self-crossing, no fold (neighbouring faces at most {g['max_fold_deg']:.0f} "
                f"degrees apart), no slit{floor}, deepest cut into a body "
                f"{1000 * g['max_penetration_dense_m']:.0f} mm (margin "
                f"{1000 * g['margin_m']:.0f} mm){took}.</span>")

    def judged(self) -> None:
        """The last fit's surface was judged (`Judge`): its verdict and misses shown."""
        self._show_warnings()

    def _show_start(self) -> None:
        """The panel's Template, or its Grid size, faces and height, as the session's start
        (an opened scenario's template or grid, `Design.start`) has them."""
        start = self._shown_start = self.design.start
        if start is None:
            return
        if start["key"] == "template":
            name = template_name(start["table"])
            if self.template.value != name:
                self._set(self.template, name)
            return
        grid = schema.Grid(**start["table"])  # (the schema's defaults where the file has none)
        self._set(self.grid_size, tuple(float(c) for c in grid.size))
        self._set(self.grid_res, tuple(int(c) for c in grid.resolution))
        self._set(self.grid_height, float(grid.height))

    # files --------------------------------------------------------------------------------
    def _may_replace(self, key: tuple, exists: bool, what: str, button: str) -> bool:
        """Whether a save may write `key`: what this tab did not save itself (another tab's,
        an earlier studio's, a batch's: every tab starts with the same Name) is replaced only
        when the save is pressed again after a warning."""
        if not exists or key in self._saved or self._replacing == key:
            self._replacing = None
            return True
        self._replacing = key
        self._status(f"{what} exists already, not saved by this tab: press **{button}** again "
                     f"to replace it, or change the Name.")
        return False

    def _save_db(self) -> None:
        from posedb import PoseLibrary

        name = check_name(self.name.value)
        with self.context.library_lock:
            taken = self.design.db is not None and name in {
                s["name"] for s in PoseLibrary(self.design.db).scenarios()}
            if not self._may_replace(("library", name), taken,
                                     f"A scenario named {name!r} in {self.design.db}",
                                     "Save to library"):
                return
            name = self.design.save_to_library(name)
        self._saved.add(("library", name))
        self._status(f"Saved the scenario {name!r} to {self.design.db}.")

    def _save_toml(self) -> None:
        path = self.out / f"{check_name(self.name.value)}.toml"
        if not self._may_replace(("toml", path), path.exists(), str(path), "Save TOML"):
            return
        path = self.design.save_toml(path)
        self._saved.add(("toml", path))
        self._status(f"Wrote {path}.")

    def _export(self) -> None:
        """Downloads the fit on screen as a zip (`Design.export_zip`); fits first when the
        session was edited since its last fit, so that what is exported is what is then shown."""
        name = check_name(self.name.value)
        if not self.design.people:
            raise DesignError("Add a person first: the scene is empty")
        if not self.design.fitted:
            self._status("Fitting before the export (the session changed since its last fit)...")
            if not self.session.fit(source=self):
                self._status("The fit was overtaken by a newer edit: nothing exported.")
                return
        self._status("Exporting...")
        data, report = self.design.export_zip(name)
        self.client.send_file_download(f"{name}.zip", data, save_immediately=True)
        self.exported = data
        with zipfile.ZipFile(io.BytesIO(data)) as pack:
            count = len(pack.namelist())
        # report.json's misses: those not shown above (the surface's bars before the fit on
        # screen was judged, a person's bar judged otherwise) are listed here
        misses = report["misses"]
        unseen = [m for m in misses if m not in self.warning_lines]
        self._status(f"Exported the fit on screen (fit {self.session.fits}) as {name}.zip: "
                     f"{count} files, {len(data)} bytes, downloaded." +
                     (f" Its report.json lists {len(misses)} missed bar(s)" if misses else "") +
                     (":" + "".join(f"\n\n- {m}" for m in unseen) if unseen else
                      ", shown above." if misses else ""))
        self._show_warnings()  # (the export judged the fit on screen: `Design.export`)

    # sessions -----------------------------------------------------------------------------
    def _join(self) -> None:
        name = self.join_name.value.strip()
        if name:
            check_name(name)
        old = self.session
        if name == old.name:
            self._status(f"This tab is in the session {name!r} already." if name else
                         "This tab is in its own session already.")
            return
        new = self.context.designs.get(name) if name else None
        alone = old.views == [self]  # (this tab's design goes when it leaves)
        if new is not None and alone and old.design.people and self._leaving != name:
            self._leaving = name  # pressed again: joins
            self._status(f"The session {name!r} has a design of its own: joining leaves this "
                         f"tab's ({len(old.design.people)} person(s)), which no other tab "
                         f"shows. Save it first (Save TOML), or press **Join session** again "
                         f"to join.")
            return
        self._leaving = None
        carried = None
        if new is None:
            fresh = Session(self.context.db, name)
            # (two tabs joining one new name at once: the first made is the one both join)
            new = self.context.designs.setdefault(name, fresh) if name else fresh
            if new is fresh:
                with old.lock:  # a new session starts from this tab's design (its fit with it)
                    carried = old.design.snapshot()
                new.design.restore(carried)
            else:
                fresh.close()
        self._leave()
        with new.lock:
            self.session = new
            new.views.append(self)
            self.selection = []
            self.redraw()
            new.judge_last()  # (a fit carried over from this tab's session, not yet judged)
        kept = " with this tab's design" if carried is not None and carried["people"] else ""
        self._status(f"Joined the session {name!r}{kept} ({len(new.views)} tab(s))." if name
                     else f"This tab's own session{kept}.")

    def _leave(self) -> None:
        old = self.session
        with old.lock:
            if self in old.views:
                old.views.remove(self)
            if not old.views:
                old.close()
                if old.name and self.context.designs.get(old.name) is old:
                    del self.context.designs[old.name]

    # drawing ------------------------------------------------------------------------------
    def redraw(self) -> None:
        """Draws the whole session anew (after an undo, a join, another tab's edit)."""
        with self.session.lock:
            labels = self._labels() or ["(none)"]
            self._syncing = True
            try:
                self.selected.options = labels
                if self.selected.value not in labels:
                    self.selected.value = labels[-1]
            finally:
                self._syncing = False
            self._show_person()
            self._show_parameters()
            if self.design.start is not self._shown_start:  # (an open, an undo, a join)
                self._show_start()
            self.selection = [j for j in self.selection if j < len(self.design.vertices)]
            self._draw_control()
            self._draw_surface()
            self._draw_people(self._pressure())
            self._draw_relaxed()
            self._history_buttons()
            self._show_warnings()

    def close(self) -> None:
        """The tab went away: leaves its session (which stops when no tab shows it)."""
        if self._watch is not None:
            self._watch.close()
        self._leave()
