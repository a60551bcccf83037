"""`sitrelax studio`: the design session (`Design`) in the browser, drawn with viser (whose web
client ships inside its Python package, so the studio works offline).

The scene is Y up, in metres. Each person hangs under a transform gizmo: dragging moves and
turns the body at once in the browser, and the new placement is written into the session;
posing, pressure and the fit run when Fit is pressed. The control mesh is drawn as lines and
points (fixed vertices red); one vertex at a time is edited with its own gizmo.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
import traceback
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from posedb.regions import support_regions
from solver.body.model import BODY_REGIONS, SHAPE_KEYS, BodyShape
from solver.contact.evaluate import peak_text
from solver.scene import schema
from solver.io.render import SKIN, SURFACE
from solver.scene.run import pressure_on_skin
from solver.mesh import quad_triangles

from .design import Design, DesignError, check_name
from .net import LOOPBACK, Front, allowed_names

MAX_UPLOAD = 5 * 1024 * 1024  # bytes: the largest control mesh file the studio takes
MAX_MESSAGE = 1024 * 1024 + 64 * 1024  # bytes of one websocket message (uploads: 512 KiB parts)
CONTROL_COLOR = (40, 40, 48)
FIXED_COLOR = (220, 50, 40)
FREE_COLOR = (40, 110, 220)


def _rgb(color) -> tuple[int, int, int]:
    return tuple(int(round(255 * c)) for c in color)


@contextlib.contextmanager
def _guarded_websocket():
    """viser's websocket server, made while this is entered, takes only connections without an
    Origin (the front checks the browser's and removes it) and messages up to MAX_MESSAGE."""
    import websockets.asyncio.server as ws_server

    original = ws_server.serve

    def serve(*args, **kwargs):
        return original(*args, **{**kwargs, "origins": [None], "max_size": MAX_MESSAGE})

    ws_server.serve = serve
    try:
        yield
    finally:
        ws_server.serve = original


def _quat_wxyz(rotation_deg) -> np.ndarray:
    x, y, z, w = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_quat()
    return np.array([w, x, y, z])


def _euler_deg(wxyz) -> list[float]:
    w, x, y, z = (float(c) for c in wxyz)
    return [round(float(a), 3) for a in Rotation.from_quat([x, y, z, w]).as_euler(
        "xyz", degrees=True)]


class Studio:
    """The studio server; `port` is the one bound (ask for 0 to get a free one)."""

    def __init__(self, db: str | None = None, host: str = "127.0.0.1", port: int = 8080,
                 out: str = "sitrelax-studio", limit: int = MAX_UPLOAD,
                 allow_hosts: tuple[str, ...] = ()):
        import viser

        self.design = Design(db)
        self.out = Path(out)
        self.limit = int(limit)
        self.lock = threading.RLock()
        with contextlib.redirect_stdout(io.StringIO()), _guarded_websocket():  # its banner
            self.server = viser.ViserServer(host=LOOPBACK, port=0, verbose=False)
        self._bound_uploads()
        # the address the designer asked for is ours: it passes the page and the websocket to
        # viser (Host and Origin ours only), and refuses request bodies (413 past the limit)
        try:
            self.front = Front(host, port, self.server.get_port(), limit,
                               names=allowed_names(host, allow_hosts))
        except OSError:
            self.stop()
            raise
        self.host, self.port = host, self.front.port
        # the studio stays on this machine: no share link through an outside relay
        self.server.request_share_url = lambda verbose=True: None
        self.server.gui.configure_theme(show_share_button=False, control_width="large")
        self.fits = 0
        self.status_text = ""
        scene = self.server.scene
        scene.set_up_direction("+y")
        self.server.initial_camera.position = (0.95, 0.8, 1.2)
        self.server.initial_camera.look_at = (0.0, 0.38, 0.0)
        scene.add_grid("/floor", width=4.0, height=4.0, plane="xz", position=(0.0, 0.0, 0.0))
        self._handles: list = []  # per person: its gizmo
        self._surface = None
        self._vertex_gizmo = None
        self._build_gui()
        self._draw_control()
        self._status("Add people from the library, then press **Fit**.")

    def _bound_uploads(self) -> None:
        """Uploads over the limit are dropped as they arrive: refused on their declared size,
        and their parts discarded once the bytes received pass it."""
        from viser import _messages

        gui = self.server.gui
        handlers = self.server._websock_server._incoming_handlers
        start, part = gui._handle_file_transfer_start, gui._handle_file_transfer_part

        def on_start(client_id, message) -> None:
            if message.size_bytes > self.limit:
                self._status(f"**Problem:** {message.filename[:100]} is {message.size_bytes} "
                             f"bytes; the studio takes control meshes up to {self.limit} bytes")
                return
            start(client_id, message)

        def on_part(client_id, message) -> None:
            state = gui._current_file_upload_states.get(message.transfer_uuid)
            if state is not None and (state["transferred_bytes"] + len(message.content)
                                      > self.limit):
                gui._current_file_upload_states.pop(message.transfer_uuid, None)
                self._status(f"**Problem:** the upload passed {self.limit} bytes; dropped")
                return
            part(client_id, message)

        for cls, old, new in ((_messages.FileTransferStartUpload, start, on_start),
                              (_messages.FileTransferPart, part, on_part)):
            handlers[cls] = [new if h == old else h for h in handlers[cls]]

    # GUI ----------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.add_markdown("**sitrelax studio**: supporting surfaces for captured poses")
        with gui.add_folder("Run"):
            self.fit = gui.add_button("Fit")
            self.relax = gui.add_button("Relax selected person")
            self.status = gui.add_markdown("")
        with gui.add_folder("People"):
            self.tags = gui.add_text("Tags", initial_value="",
                                     hint="a tag expression, e.g. sit and not high")
            self.search = gui.add_button("Search library")
            self.pose = gui.add_dropdown("Pose", self._pose_options(""))
            self.frame = gui.add_number("Frame (recordings)", initial_value=39, min=0, step=1)
            self.add = gui.add_button("Add person")
            self.selected = gui.add_dropdown("Selected", ["(none)"])
            self.shape = {key: gui.add_slider(key.capitalize(), min=0.0, max=1.0, step=0.05,
                                              initial_value=getattr(BodyShape(), key))
                          for key in SHAPE_KEYS}
            support = support_regions(schema.default(schema.Person, "support"))
            self.parts = {region: gui.add_checkbox(f"Support {region.replace('_', ' ')}",
                                                   initial_value=region in support)
                          for region in BODY_REGIONS}
            self.apply = gui.add_button("Apply shape and support")
            self.remove = gui.add_button("Remove person")
        grid, params = schema.Grid(), self.design.params  # the schema's defaults
        with gui.add_folder("Surface"):
            self.grid_size = gui.add_vector2("Grid size (m)", initial_value=tuple(grid.size),
                                             min=(0.05, 0.05), max=(10.0, 10.0), step=0.05)
            self.grid_res = gui.add_vector2("Grid faces", initial_value=tuple(grid.resolution),
                                            min=(1, 1), max=(40, 40), step=1)
            self.grid_height = gui.add_number("Grid height (m)", initial_value=grid.height,
                                              min=-5.0, max=5.0, step=0.01)
            self.new_grid = gui.add_button("New grid")
            self.upload = gui.add_upload_button("Load control mesh (OBJ)", mime_type=".obj")
            self.vertex = gui.add_number("Control vertex", initial_value=0, min=0, step=1)
            self.fixed = gui.add_checkbox("Fixed", initial_value=False)
            self.level = gui.add_slider("Level", min=1, max=3, step=1,
                                        initial_value=params["level"])
            self.sigma = gui.add_number("Sigma", initial_value=params["sigma"], min=0.0,
                                        max=100.0, step=0.001)
            self.tau = gui.add_slider("Tau max", min=0.0, max=1.0, step=0.05,
                                      initial_value=params["tau_max"])
            self.margin = gui.add_slider("Margin (m)", min=0.0, max=0.1, step=0.005,
                                         initial_value=params["margin"])
            self.adopt = gui.add_button("Start from the fitted mesh")
        with gui.add_folder("Save"):
            self.name = gui.add_text("Name", initial_value="studio-design")
            self.save_db = gui.add_button("Save to library")
            self.save_toml = gui.add_button("Save TOML")
            self.export = gui.add_button("Export")
        self._wire()

    def _wire(self) -> None:
        actions = [
            (self.search, lambda: self._set_options(self._pose_options(self.tags.value))),
            (self.add, self._add_person),
            (self.apply, self._apply_person),
            (self.remove, self._remove_person),
            (self.new_grid, self._new_grid),
            (self.adopt, self._adopt),
            (self.fit, self.run_fit),
            (self.relax, self._relax),
            (self.save_db, self._save_db),
            (self.save_toml, self._save_toml),
            (self.export, self._export),
        ]
        for button, action in actions:
            button.on_click(lambda _event, action=action: self._guarded(action))
        self.selected.on_update(lambda _e: self._guarded(self._show_person))
        self.vertex.on_update(lambda _e: self._guarded(self._select_vertex))
        self.fixed.on_update(lambda _e: self._guarded(self._fix_vertex))
        for name, handle in (("level", self.level), ("sigma", self.sigma),
                             ("tau_max", self.tau), ("margin", self.margin)):
            handle.on_update(lambda _e, name=name, handle=handle: self._guarded(
                lambda: self.design.set_parameter(name, handle.value)))
        self.upload.on_upload(lambda _e: self._guarded(self._load_mesh))

    def _guarded(self, action) -> None:
        """Runs one action at a time; a problem becomes the status line, not a crash."""
        with self.lock:
            try:
                action()
            except (ValueError, OSError, KeyError) as exc:
                self._status(f"**Problem:** {exc}")
            except Exception as exc:  # noqa: BLE001 (the studio stays up; the trace is shown)
                self._status(f"**Internal error:** {type(exc).__name__}: {exc}\n\n```\n"
                             f"{traceback.format_exc(limit=3)}\n```")

    def _status(self, text: str) -> None:
        self.status_text = text
        self.status.content = text

    # people ---------------------------------------------------------------------------------
    def _pose_options(self, expr: str) -> list[str]:
        from capture.recordings import bundled_recordings

        names: list[str] = []
        if self.design.db is not None:
            from posedb import PoseLibrary

            names = PoseLibrary(self.design.db).search_poses(expr.strip() or None)
        return names + [f"recording: {r}" for r in bundled_recordings()] or ["(none)"]

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

    def add_person(self, pose: str) -> int:
        """Adds a person (also what the Add button does with the chosen pose)."""
        k = self.design.add_person(pose)
        self._draw_people()
        self.selected.value = self._labels()[k]
        self._status(f"Added {self.design.people[k]['name']} ({pose}).")
        return k

    def _add_person(self) -> None:
        self.add_person(self._pose_spec())

    def _labels(self) -> list[str]:
        return [f"{k + 1}: {p['name']} ({p['pose']})" for k, p in enumerate(self.design.people)]

    def _selected_index(self) -> int:
        labels = self._labels()
        if self.selected.value not in labels:
            raise DesignError("Select a person first")
        return labels.index(self.selected.value)

    def _show_person(self) -> None:
        if self.selected.value not in self._labels():
            return
        p = self.design.people[self._selected_index()]
        body = p.get("body", {})
        for key, slider in self.shape.items():
            slider.value = float(body.get(key, getattr(BodyShape(), key)))
        support = support_regions(p["support"])  # a use or coarse part as its regions
        for region, box in self.parts.items():
            box.value = region in support

    def _apply_person(self) -> None:
        k = self._selected_index()
        support = [part for part, box in self.parts.items() if box.value]
        body = {key: float(s.value) for key, s in self.shape.items()}
        self.design.update_person(k, body=body, support=support)
        self._draw_people()
        self._status(f"{self.design.people[k]['name']}: shape and support set.")

    def _remove_person(self) -> None:
        self.design.remove_person(self._selected_index())
        self._draw_people()
        self._clear_surface()
        self._status("Removed.")

    def _draw_people(self, pressure: list[np.ndarray] | None = None,
                     peak: float | None = None) -> None:
        scene = self.server.scene
        for handle in self._handles:
            handle.remove()
        self._handles = []
        for k, person in enumerate(self.design.people):
            origin = dict(person, position=[0.0, 0.0, 0.0], rotation_deg=[0.0, 0.0, 0.0])
            local = self.design.place(origin)
            gizmo = scene.add_transform_controls(
                f"/people/p{k}", scale=0.35, position=tuple(person["position"]),
                wxyz=tuple(_quat_wxyz(person["rotation_deg"])), active_axes=(True, True, True))
            gizmo.on_update(lambda _e, k=k, gizmo=gizmo: self._guarded(
                lambda: self._moved(k, gizmo)))
            if pressure is not None:
                self._colored_mesh(f"/people/p{k}/body", local.vertices, local.body.triangles,
                                   pressure_on_skin(pressure[k], peak))
            else:
                scene.add_mesh_simple(f"/people/p{k}/body", local.vertices,
                                      local.body.triangles, color=_rgb(SKIN))
            self._handles.append(gizmo)
        labels = self._labels() or ["(none)"]
        self.selected.options = labels
        if self.selected.value not in labels:
            self.selected.value = labels[-1]

    def _colored_mesh(self, name: str, vertices, triangles, colors) -> None:
        import trimesh

        mesh = trimesh.Trimesh(vertices, triangles, process=False)
        rgba = np.concatenate([np.asarray(colors), np.ones((len(colors), 1))], axis=1)
        mesh.visual.vertex_colors = (rgba * 255).astype(np.uint8)
        self.server.scene.add_mesh_trimesh(name, mesh)

    def _moved(self, k: int, gizmo) -> None:
        if k >= len(self.design.people):
            return
        position = [round(float(c), 4) for c in gizmo.position]
        self.design.update_person(k, position=position,
                                  rotation_deg=_euler_deg(gizmo.wxyz))

    # the control mesh ---------------------------------------------------------------------
    def _new_grid(self) -> None:
        size = tuple(float(c) for c in self.grid_size.value)
        res = tuple(int(round(c)) for c in self.grid_res.value)
        self.design.new_grid(size, res, float(self.grid_height.value))
        self._clear_surface()
        self._draw_control()
        self._status(f"New {res[0]} x {res[1]} grid, {size[0]:g} x {size[1]:g} m.")

    def _load_mesh(self) -> None:
        import tempfile

        upload = self.upload.value
        if len(upload.content) > MAX_UPLOAD:
            raise DesignError(f"{upload.name} is {len(upload.content)} bytes; the studio takes "
                              f"control meshes up to {MAX_UPLOAD} bytes")
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / Path(upload.name).name
            path.write_bytes(upload.content)
            self.design.load_control_mesh(path)
        self._clear_surface()
        self._draw_control()
        self._status(f"Loaded {upload.name}: {len(self.design.vertices)} control vertices.")

    def _select_vertex(self) -> None:
        j = int(self.vertex.value)
        if not 0 <= j < len(self.design.vertices):
            raise DesignError(f"Expected a control vertex in 0..{len(self.design.vertices) - 1}")
        self.fixed.value = j in self.design.fixed
        self._draw_control()

    def _fix_vertex(self) -> None:
        self.design.set_fixed(int(self.vertex.value), bool(self.fixed.value))
        self._draw_control()

    def _vertex_moved(self, gizmo) -> None:
        self.design.move_vertex(int(self.vertex.value), [float(c) for c in gizmo.position])
        self._draw_control(keep_gizmo=True)

    def _draw_control(self, keep_gizmo: bool = False) -> None:
        scene = self.server.scene
        v, f = self.design.vertices, self.design.faces
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 3]], f[:, [3, 0]]])
        edges = np.unique(np.sort(edges, axis=1), axis=0)
        scene.add_line_segments("/control/edges", v[edges], CONTROL_COLOR, thickness=2.0,
                                thickness_units="screen")
        colors = np.array([FIXED_COLOR if j in self.design.fixed else FREE_COLOR
                           for j in range(len(v))], dtype=np.uint8)
        scene.add_point_cloud("/control/vertices", v, colors, point_size=0.015,
                              point_shape="circle")
        j = int(self.vertex.value)
        if keep_gizmo or not 0 <= j < len(v):
            return
        if self._vertex_gizmo is not None:
            self._vertex_gizmo.remove()
        self._vertex_gizmo = scene.add_transform_controls(
            "/control/handle", scale=0.12, disable_rotations=True, position=tuple(v[j]))
        gizmo = self._vertex_gizmo
        gizmo.on_update(lambda _e: self._guarded(lambda: self._vertex_moved(gizmo)))

    def _adopt(self) -> None:
        self.design.adopt_fit()
        self._draw_control()
        self._status("The fitted control mesh is the start now.")

    # running ------------------------------------------------------------------------------
    def run_fit(self) -> None:
        """Fits the session and draws the surface and each body's pressure (the Fit button)."""
        self._status("Fitting...")
        outcome = self.design.fit()
        r = outcome.result
        quads = r.surface_faces
        tris = quad_triangles(quads)
        self._surface = self.server.scene.add_mesh_simple(
            "/surface", r.surface, tris, color=_rgb(SURFACE), side="double")
        peak = max((float(p.max()) for p in outcome.pressure), default=1.0) or 1.0
        self._draw_people(outcome.pressure, peak)
        self.fits += 1
        rows = "\n".join(
            f"| {p['name'].split(' (')[0]} | {p['coverage']:.2f} | "
            f"{peak_text(p)} / {peak_text(p['flat'])} | "
            f"{1000 * p['max_penetration_m']:.0f} |" for p in outcome.persons)
        self._status(f"**Fitted** in {r.iterations} iterations, {outcome.seconds:.2f} s "
                     f"({r.stop_reason.split(':')[0]}).\n\n"
                     "| person | coverage | peak kPa (flat) | into skin mm |\n|---|---|---|---|\n"
                     f"{rows}")

    def _clear_surface(self) -> None:
        if self._surface is not None:
            self._surface.remove()
            self._surface = None

    def _relax(self) -> None:
        k = self._selected_index()
        res = self.design.relax(k)
        self.server.scene.add_mesh_simple(f"/relaxed/p{k}", res.vertices, res.faces,
                                          color=(150, 200, 150), opacity=0.8)
        self._status(f"Relaxed {self.design.people[k]['name']} in {res.seconds:.2f} s: mean "
                     f"support distance {100 * res.before['mean_support_distance_m']:.1f} -> "
                     f"{100 * res.after['mean_support_distance_m']:.1f} cm (green); "
                     f"{res.summary}.")

    def _save_db(self) -> None:
        name = self.design.save_to_library(check_name(self.name.value))
        self._status(f"Saved the scenario {name!r} to {self.design.db}.")

    def _save_toml(self) -> None:
        path = self.design.save_toml(self.out / f"{check_name(self.name.value)}.toml")
        self._status(f"Wrote {path}.")

    def _export(self) -> None:
        folder = self.out / check_name(self.name.value)
        report = self.design.export(folder)
        self.server.send_file_download("surface.obj", (folder / "surface.obj").read_bytes())
        self._status(f"Exported to {folder} ({len(report['files'])} files); surface.obj "
                     "downloaded.")

    # life ---------------------------------------------------------------------------------
    def wait(self) -> None:
        while True:
            time.sleep(1.0)

    def stop(self) -> None:
        if getattr(self, "front", None) is not None:
            self.front.stop()
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()
