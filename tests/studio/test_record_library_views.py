"""The studio's Record and Library views: their handlers driven against a viser server on
loopback (no browser) with a temporary library, and, under the slow mark, both views in a real
headless browser (Debian's chromium), mounted in a tab group per client as the studio mounts
its views."""

from __future__ import annotations

import contextlib
import io
import os
import time
from pathlib import Path

import numpy as np
import pytest

from capture import read_bvh, skeleton_fk
from capture.recordings import resolve_path
from posedb import PoseLibrary
from posedb.record import journal_dir
from studio.context import StudioContext
from studio.skeleton_draw import pose_world, skeleton_thumbnail

from tests.conftest import high_sit_library as shared_high_sit_library
from tests.studio.test_studio_browser import ARTIFACTS, CHROMIUM, DRIVER, _browser, _wait

ROOT = Path(__file__).resolve().parents[2]
AXIS = "axis_neuron_standing_yxz.bvh"


def _server():
    import viser

    with contextlib.redirect_stdout(io.StringIO()):  # its banner
        return viser.ViserServer(host="127.0.0.1", port=0, verbose=False)


def _stop(server) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        server.stop()


def high_sit_library(path: Path, poses=((10, "early", ["test"]),)) -> Path:
    """A new pose library at `path` with the bundled high-sit recording as a take (tagged
    sit) and `poses` (frame, name, tags) of it."""
    return shared_high_sit_library(path, poses, take_tags=("sit",))


@pytest.fixture
def library(tmp_path) -> Path:
    return high_sit_library(tmp_path / "poses.h5")


def test_record_view_records_a_replay_and_stores_the_marked_poses(library, tmp_path):
    from studio.record import RecordView

    server = _server()
    context = StudioContext(db=str(library), out=tmp_path, limit=1 << 20)
    view = RecordView(server, server.gui.add_tab_group().add_tab("Record"), context)
    try:
        assert view.choice.value == f"practice: replay {AXIS}"
        view._guarded(view.do_mark)  # before a connection: a clear problem, not a crash
        assert "Connect to a source first" in view.status.content
        view._guarded(view.do_connect)
        assert view.status.content.startswith("Connected to tcp://127.0.0.1:")
        _wait(lambda: view.figure.bones is not None, 10, "the live skeleton")
        view.with_body.value = True
        _wait(lambda: view.figure.body is not None, 20, "the live body")
        # posed from a frame drawn a moment before the skeleton now shown: a looser fit
        _assert_body_around_skeleton(view.figure, within=0.5)
        view._guarded(view.do_mark)
        assert "Start a take first" in view.status.content
        view.take_name.value, view.take_tags.value = "live", "session"
        view._guarded(view.do_start)
        assert "Recording take **live**" in view.status.content
        _wait(lambda: view.stream.frames_in_take > 60, 10, "frames of the take")
        view.pose_name.value, view.pose_tags.value = "reach", "stand, arms"
        view.parts["feet"].value = True
        view._guarded(view.do_mark)
        time.sleep(0.3)
        view.pose_name.value = "reach"  # the same name again: refused, nothing marked
        view._guarded(view.do_mark)
        assert "already" in view.status.content
        view.pose_name.value, view.pose_tags.value = "", "stand"
        view._guarded(view.do_mark)
        _wait(lambda: "2 marked" in view.readout.content, 5, "the readout")
        assert "fps" in view.readout.content and "dropped 0" in view.readout.content
        view._guarded(view.do_stop)
        assert "Stored take **live**" in view.status.content, view.status.content
        assert view.take_name.value == "live-2"
    finally:
        view.close()
        _stop(server)
    lib = PoseLibrary(library)
    take = lib.take("live")
    assert take.kind == "stream" and take.tags == ("session",)
    poses = {p.name: p for p in lib.find_poses(take="live")}
    assert len(poses) == 2 and poses["reach"].tags == ("arms", "session", "stand")
    assert poses["reach"].supports == ("pelvis", "thighs", "feet")
    (unnamed,) = set(poses) - {"reach"}
    assert unnamed == f"live-f{poses[unnamed].frame:05d}"
    assert poses[unnamed].frame > poses["reach"].frame
    # the first pose is the frame that was on screen: its receive time is the mark's
    data = lib.take_data("live")
    assert data.received_at[poses["reach"].frame] == pytest.approx(view.marked[0]["received_at"],
                                                                    abs=1e-6)
    # and the take holds what the replay sent, frame for frame (the bundled recording)
    axis = read_bvh(resolve_path(f"bundled:{AXIS}"), unit=None)
    want = axis.motion.channels[data.frame_indices % axis.motion.num_frames]
    np.testing.assert_array_equal(data.channels, want.astype(np.float32))
    assert not list(journal_dir(library).glob("*.raw"))


def test_record_view_refuses_what_it_cannot_do(tmp_path):
    from studio.record import URL_CHOICE, RecordView

    server = _server()
    view = RecordView(server, server.gui.add_tab_group().add_tab("Record"),
                      StudioContext(db=None, out=tmp_path, limit=1 << 20))
    try:
        view.choice.value = URL_CHOICE
        view.url.value = "ftp://nowhere"
        view._guarded(view.do_connect)
        assert "Expected a source URL" in view.status.content and view.stream is None
        view.choice.value = f"practice: replay {AXIS}"
        view._guarded(view.do_connect)
        view._guarded(view.do_start)
        assert "needs a pose library" in view.status.content
    finally:
        view.close()
        _stop(server)


def test_library_view_scrubs_accepts_a_hold_and_edits(library, tmp_path):
    from studio.library_view import LibraryView

    server = _server()
    context = StudioContext(db=str(library), out=tmp_path, limit=1 << 20)
    view = LibraryView(server, server.gui.add_tab_group().add_tab("Library"), context)
    try:
        assert view.found.content == "1 take(s), 1 pose(s)"
        # one picture of the pose, one of the take, each a PNG of the skeleton
        assert view.pose_gallery.content.count("<img") == 1
        assert view.take_gallery.content.count("<img") == 1
        assert ">early</b><br>high_sit #10: test<" in view.pose_gallery.content
        view.take.value = "high_sit"
        view._guarded(lambda: view.load_take("high_sit"))
        # the holds are those `db suggest` finds; the timeline starts on the first
        from posedb.suggest import suggest_poses

        rows = suggest_poses(PoseLibrary(library), "high_sit")
        assert [h.frame for h in view.holds] == [r["frame"] for r in rows] == [39]
        assert view.frame.value == 39
        # scrubbing draws the take's skeleton at that frame
        view.frame.value = 60
        view._show_frame()
        bvh = read_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"))
        want = skeleton_fk(bvh.skeleton, bvh.motion.channels[60]).positions
        # viser keeps (and sends) points as float16: 1 mm steps at a metre
        centre = bvh.skeleton.root_positions(bvh.motion.channels).mean(axis=0) * [1, 0, 1]
        np.testing.assert_allclose(view.figure.joints.points, want - centre, atol=2e-3)
        _assert_body_around_skeleton(view.figure)
        view.with_body.value = False
        assert not view.figure.body.visible
        view.new_tags.value = "high"
        view._guarded(view.do_accept_hold)
        assert "Added pose **high_sit-f00039** at frame 39" in view.status.content
        # accepting it again adds nothing: that pose is chosen (it failed on the duplicate name)
        view._guarded(view.do_accept_hold)
        assert "Frame 39 of high_sit is pose **high_sit-f00039** already" in view.status.content
        assert view.pose.value == "high_sit-f00039"
        assert len(PoseLibrary(library).poses()) == 2
        view.search_text.value = "high and sit"
        view._guarded(view.do_search)
        assert view.pose.options == ("high_sit-f00039",)
        view.pose.value = "high_sit-f00039"
        view.rename_to.value = "perch"
        view._guarded(view.do_rename)
        view.edit_tags.value = "favourite"
        view._guarded(lambda: view.do_tag(remove=False))
        view.pose.value, view.rename_to.value = "perch", "a/b"
        view._guarded(view.do_rename)
        assert "without '/'" in view.status.content
        view.pose.value = "early"
        view._guarded(view.do_delete)
        # a change made elsewhere (another tab, a command) is listed within a few seconds,
        # the pose chosen staying chosen
        view.pose.value = "perch"
        PoseLibrary(library).add_pose("high_sit", 5, "outside", tags=["high", "sit"])
        _wait(lambda: "outside" in view.pose.options, 10, "the change made elsewhere")
        assert view.pose.value == "perch"
    finally:
        view.close()
        _stop(server)
    lib = PoseLibrary(library)
    assert [p.name for p in lib.poses()] == ["perch", "outside"]
    perch = lib.pose("perch")
    assert perch.frame == 39 and perch.tags == ("favourite", "high", "sit")


def _assert_body_around_skeleton(figure, within: float = 0.25) -> None:
    """The posed body (all its 13,380 vertices) wraps the skeleton drawn with it: the boxes'
    low corners and their far sides across (x, z) agree within `within` m, and the skin rises
    above the top joint (the skull over the head joint; the average body is not the
    subject's size)."""
    skin = np.asarray(figure.body.vertices, dtype=np.float64)
    joints = np.asarray(figure.joints.points, dtype=np.float64)
    assert skin.shape == (13380, 3) and np.isfinite(skin).all()
    assert np.abs(skin.min(axis=0) - joints.min(axis=0)).max() < within
    assert np.abs(skin.max(axis=0) - joints.max(axis=0))[[0, 2]].max() < within
    assert skin[:, 1].max() > joints[:, 1].max()


def test_library_view_without_a_library_says_so(tmp_path):
    from studio.library_view import LibraryView

    server = _server()
    view = LibraryView(server, server.gui.add_tab_group().add_tab("Library"),
                       StudioContext(db=None, out=tmp_path, limit=1 << 20))
    try:
        assert "start the studio with --db" in view.status.content
        view._guarded(view.do_accept_hold)
        assert "Choose a take with a suggested hold first" in view.status.content
        view._guarded(view.do_search)
        assert "No pose library" in view.status.content
    finally:
        view.close()
        _stop(server)


def test_a_thumbnail_is_the_skeleton_seen_from_the_front():
    bvh = read_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"))
    positions = skeleton_fk(bvh.skeleton, bvh.motion.channels[39]).positions
    img = skeleton_thumbnail(positions, bvh.skeleton.parents)
    assert img.shape == (112, 112, 3) and img.dtype == np.uint8
    inked = (img < 200).any(axis=2)
    rows, cols = np.flatnonzero(inked.any(axis=1)), np.flatnonzero(inked.any(axis=0))
    # the figure fills the square within its 8 % margin, the tall way
    assert rows[-1] - rows[0] >= 0.8 * 112 and rows[0] <= 0.08 * 112 + 3
    # image rows are world Y, downwards: the body turned upside down is the picture flipped
    flipped = skeleton_thumbnail(positions * [1.0, -1.0, 1.0], bvh.skeleton.parents)
    ink, ink_flipped = inked.sum(axis=1), (flipped < 200).any(axis=2).sum(axis=1)
    assert np.corrcoef(ink, ink_flipped[::-1])[0, 1] > 0.9
    assert np.corrcoef(ink, ink_flipped)[0, 1] < 0.5
    with pytest.raises(ValueError, match="finite joint positions"):
        skeleton_thumbnail(np.full((3, 3), np.nan), np.array([-1, 0, 1]))


def test_the_pictures_escape_what_users_typed():
    from studio.library_view import gallery_html

    page = gallery_html([("AAAA", "<img src=x onerror=alert(1)>", "a & b")], more=3)
    assert "<img src=x" not in page and "&lt;img src=x onerror=alert(1)&gt;" in page
    assert "a &amp; b" in page and "3 more" in page


def test_a_pose_is_drawn_from_its_own_rotations(library):
    lib = PoseLibrary(library)
    _, skeleton, rot, root = lib.pose_data("early")
    data = lib.take_data("high_sit")
    want = skeleton_fk(data.skeleton, data.motion().channels[10]).positions
    np.testing.assert_allclose(pose_world(skeleton, rot, root).positions, want, atol=1e-4)


def _mount(server, context, views):
    """Mounts the views in a tab group for every client that connects, as the studio does:
    the 3D view shows the first view's nodes only (viser tells the server no tab switch; the
    studio's "3D view shows" chooses, and a test shows another view's by its `root`)."""
    mounted = []

    @server.on_client_connect
    def _(client) -> None:
        group = client.gui.add_tab_group()
        made = {label: cls(client, group.add_tab(label), context) for label, cls in views}
        for k, view in enumerate(made.values()):
            view.root.visible = k == 0
        mounted.append(made)

    return mounted


@pytest.mark.slow
@pytest.mark.skipif(not (CHROMIUM and DRIVER) and not os.environ.get("CI"),
                    reason="needs Debian's chromium and chromium-driver")
def test_record_and_library_views_in_a_browser(library, tmp_path):
    """Record a replayed stream while marking two poses (the button and the key M), find them
    in the Library view with their tags, scrub a take and accept a suggested hold."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from studio.library_view import LibraryView
    from studio.record import RecordView

    shots = Path(os.environ.get("SITRELAX_SHOTS", tmp_path / "shots"))
    shots.mkdir(parents=True, exist_ok=True)
    server = _server()
    server.scene.set_up_direction("+y")
    server.initial_camera.position = (1.6, 1.4, 2.6)
    server.initial_camera.look_at = (0.0, 0.8, 0.0)
    server.scene.add_grid("/floor", width=4.0, height=4.0, plane="xz")
    context = StudioContext(db=str(library), out=tmp_path, limit=1 << 20)
    mounted = _mount(server, context, (("Record", RecordView), ("Library", LibraryView)))
    driver = _browser()
    step = iter(range(1, 100))

    def shot(name: str) -> None:
        time.sleep(1.0)
        driver.save_screenshot(str(shots / f"{next(step):02d}-{name}.png"))

    def button(label):
        found = driver.find_elements(By.XPATH, f"//button[normalize-space(.)='{label}']")
        visible = [b for b in found if b.is_displayed()]
        return visible[0] if visible else None

    def click(label):
        target = button(label)
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", target)
        target.click()

    def field(label):
        """The text input of a labelled viser field that is on screen."""
        for el in driver.find_elements(By.XPATH, f"//label[normalize-space(.)='{label}']"):
            if el.is_displayed():  # the input sits in the label's row
                return el.find_element(
                    By.XPATH, "./ancestor::div[contains(@class, 'mantine-Flex-root')][1]//input")
        raise AssertionError(f"no field labelled {label!r} on screen")

    def type_into(label, text):
        box = field(label)
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", box)
        box.click()
        box.send_keys(Keys.CONTROL, "a")
        box.send_keys(Keys.BACKSPACE)
        box.send_keys(text)
        box.send_keys(Keys.ENTER)
        time.sleep(0.3)

    def to_top(title: str) -> None:
        """Scrolls the panel back to a view's title (its status line under it)."""
        heading = driver.find_element(By.XPATH, f"//*[contains(text(), '{title}')]")
        driver.execute_script("arguments[0].scrollIntoView({block: 'start'})", heading)

    def page() -> str:
        return driver.find_element(By.TAG_NAME, "body").text

    try:
        driver.get(f"http://127.0.0.1:{server.get_port()}")
        _wait(lambda: mounted and button("Connect"), 90, "the Record view")
        for close in driver.find_elements(By.CSS_SELECTOR,
                                          "button.mantine-Notification-closeButton"):
            close.click()  # the note that WebGL runs in software
        record = mounted[0]["Record"]
        shot("record-start")
        click("Connect")
        _wait(lambda: record.figure.bones is not None, 20, "the live skeleton")
        _wait(lambda: "fps" in page(), 20, "the frame rate on the page")
        shot("record-connected")
        body_box = field("Show the body")
        driver.execute_script("arguments[0].click()", body_box)  # mantine hides the input
        _wait(lambda: record.figure.body is not None, 30, "the live body")
        type_into("Take name", "browser-take")
        type_into("Take tags", "session")
        click("Start take")
        _wait(lambda: record.stream.recorder is not None, 20, "the take to start")
        _wait(lambda: record.stream.frames_in_take > 100, 20, "frames of the take")
        type_into("Pose name", "wave")
        type_into("Pose tags", "stand arms")
        time.sleep(1.0)
        assert record.marked == []  # the m typed in "arms" is text, not the key
        click("Mark pose (M)")
        _wait(lambda: len(record.marked) == 1, 20, "the first mark (button)")
        time.sleep(1.0)
        type_into("Pose name", "second")
        type_into("Pose tags", "stand")
        driver.execute_script("document.activeElement.blur()")  # the key, in no field
        ActionChains(driver).send_keys("m").perform()
        _wait(lambda: len(record.marked) == 2, 20, "the second mark (key M)")
        _wait(lambda: "2 marked" in page(), 20, "the marks in the readout")
        to_top("a live stream into the pose library")
        shot("record-marked")
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(ARTIFACTS / "studio-record.png"))
        click("Stop take")
        _wait(lambda: "Stored take" in page(), 30, "the take to be stored")
        shot("record-stored")

        driver.find_element(By.XPATH, "//*[@role='tab'][normalize-space(.)='Library']").click()
        record.root.visible = False  # viser tells the server no tab switch: the studio hides
        mounted[0]["Library"].root.visible = True  # one view's nodes and shows the other's
        _wait(lambda: button("Search"), 20, "the Library view")
        click("Refresh")
        type_into("Tags", "session and stand")
        click("Search")
        library_view = mounted[0]["Library"]
        _wait(lambda: "2 pose(s) match" in page(), 20, "the marked poses found")
        text = page()
        assert "wave" in text and "second" in text and "arms session stand" in text
        assert text.count("browser-take #") == 2
        shot("library-found")
        # the timeline: the CMU take (first on the list), on its suggested hold; scrubbed back
        # with the slider's keys, then its hold accepted as a tagged pose
        _wait(lambda: library_view.data is not None
              and library_view.data.take.name == "high_sit", 20, "the take on the timeline")
        _wait(lambda: "1 suggested hold(s)" in page(), 20, "the holds on the page")
        thumb = driver.find_element(By.XPATH, "//label[normalize-space(.)='Frame']/ancestor::"
                                    "div[contains(@class, 'mantine-Flex-root')][1]"
                                    "//*[@role='slider']")
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", thumb)
        assert thumb.get_attribute("aria-valuenow") == "39"
        thumb.send_keys(*[Keys.ARROW_LEFT] * 19)
        _wait(lambda: library_view.frame.value == 20, 20, "the timeline at frame 20")
        _wait(lambda: abs(float(library_view.figure.joints.points[:, 1].max())
                          - _top(library, 20)) < 2e-3, 10, "the skeleton at frame 20")
        shot("library-scrubbed")
        click("Go to hold")
        _wait(lambda: library_view.frame.value == 39, 10, "the hold's frame")
        type_into("Pose tags", "high")
        click("Accept hold as pose")
        _wait(lambda: "Added pose" in page(), 20, "the hold accepted")
        type_into("Tags", "high or session")
        click("Search")
        _wait(lambda: "3 pose(s) match" in page(), 20, "the new pose listed")
        assert "high_sit-f00039" in page()
        # the new pose picked from the list is drawn, its tags and regions shown
        picker = field("Pose")
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", picker)
        picker.click()
        option = _wait(lambda: [o for o in driver.find_elements(By.XPATH, "//*[@role='option']")
                                if o.text.strip() == "high_sit-f00039"], 10, "the pose list")
        option[0].click()
        _wait(lambda: "frame 39 of high_sit; tags high sit" in page(), 20, "the pose's details")
        to_top("takes and poses of the pose library")
        shot("library-accepted")
        driver.save_screenshot(str(ARTIFACTS / "studio-library.png"))
    finally:
        for made in mounted:
            for view in made.values():
                view.close()
        driver.quit()
        _stop(server)
    lib = PoseLibrary(library)
    wave, second = lib.pose("wave"), lib.pose("second")
    assert wave.tags == ("arms", "session", "stand") and second.tags == ("session", "stand")
    assert lib.take(wave.take).name == "browser-take" and second.frame > wave.frame
    accepted = lib.pose("high_sit-f00039")
    assert accepted.frame == 39 and accepted.tags == ("high", "sit")


def _top(library: Path, frame: int) -> float:
    data = PoseLibrary(library).take_data("high_sit")
    return float(skeleton_fk(data.skeleton, data.motion().channels[frame]).positions[:, 1].max())


_RECORDING_STUDIO = """
import sys, time, contextlib, io
import viser
from studio.context import StudioContext
from studio.record import RecordView
with contextlib.redirect_stdout(io.StringIO()):
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
view = RecordView(server, server.gui.add_tab_group().add_tab("Record"),
                  StudioContext(db=sys.argv[1], out=".", limit=1))
view.do_connect()
view.take_name.value = "killed"
view.do_start()
while view.stream.frames_in_take < 250:
    time.sleep(0.05)
view.pose_name.value, view.pose_tags.value = "held", "sit"
view.do_mark()
print(view.stream.frames_in_take, flush=True)
time.sleep(60)
"""


@pytest.mark.slow
def test_a_studio_killed_while_recording_leaves_its_take_and_marks_to_recover(library):
    import signal
    import subprocess
    import sys

    from posedb.record import recordings, recover

    child = subprocess.Popen([sys.executable, "-c", _RECORDING_STUDIO, str(library)],
                             stdout=subprocess.PIPE, text=True, cwd=ROOT,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        frames_at_mark = int(child.stdout.readline())
        time.sleep(1.5)
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    finally:
        child.kill()
    assert [t.name for t in PoseLibrary(library).takes()] == ["high_sit"]  # untouched
    assert [(r.take, r.running) for r in recordings(library)] == [("killed", False)]
    assert [r["status"] for r in recover(library)] == ["recovered"]
    lib = PoseLibrary(library)
    take = lib.take("killed")
    # everything up to the mark and the second after it, less at most the last half second
    assert take.frames >= frames_at_mark + 125
    held = lib.pose("held")
    assert held.take == take.id and held.tags == ("sit",) and held.frame < frames_at_mark
