"""`sitrelax serve`: the HTTP API as a client sees it, on a real server over loopback."""

from __future__ import annotations

import http.client
import json
import os
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.config import SchemathesisConfig

from solver.bench import _example_path
from studio.api import ApiThread, create_app
from studio.net import exposure_warning, is_loopback

from tests.conftest import high_sit_library, listening_addresses

SINGLE = tomllib.loads(_example_path("single_seated").read_text())


def _library(path: Path) -> Path:
    return high_sit_library(path, [(39, "perch", ["sit", "high"]),
                                   (35, "perch_early", ["sit"])])


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    db = _library(tmp_path_factory.mktemp("api") / "poses.h5")
    server = ApiThread(db, limit=1024 * 1024)
    yield server
    server.stop()


def _request(api, method: str, path: str, body=None, headers=None):
    conn = http.client.HTTPConnection(api.host, api.port, timeout=60)
    data = json.dumps(body).encode() if body is not None and not isinstance(body, bytes) \
        else body
    conn.request(method, path, body=data,
                 headers={"Content-Type": "application/json", **(headers or {})})
    response = conn.getresponse()
    payload = response.read()
    conn.close()
    return response.status, json.loads(payload) if payload else None


@pytest.mark.slow  # the default run stays within its time
def test_fit_of_one_person_answers_with_the_surface_and_its_evaluation(api):
    status, reply = _request(api, "POST", "/api/fit", SINGLE)
    assert status == 200, reply
    # an 8 x 6 grid subdivided three times: (8*8+1) x (6*8+1) vertices, 8*6*64 quads
    assert len(reply["surface"]["vertices"]) == 65 * 49
    assert len(reply["surface"]["faces"]) == 8 * 6 * 64
    assert len(reply["control"]["vertices"]) == 9 * 7
    person = reply["persons"][0]
    assert person["coverage"] >= 0.9 and person["support"] == ["pelvis", "thighs"]
    assert "converged" in reply["stop_reason"]
    # the same person in a chair (a template with a back, supporting the back too) rests on it
    chair = json.loads(json.dumps(SINGLE))
    chair["surface"] = {k: v for k, v in chair["surface"].items() if k != "grid"}
    chair["surface"]["template"] = {"kind": "chair"}
    chair["person"][0]["support"] = "chair"
    status, reply = _request(api, "POST", "/api/fit", chair)
    assert status == 200, reply
    person = reply["persons"][0]
    assert person["equilibrium"]["stable"] and person["peak_pressure_kpa"] > 0
    # the flat seat a chair is judged against has no back: it does not hold this sitter
    assert person["flat"]["supported"] is False and person["flat"]["peak_pressure_kpa"] is None


def test_a_fit_with_relief_rounds_relieves_the_seat(api):
    """The scenario's [relief] rounds run behind the API (`relieve_fit`, as `sitrelax fit`
    runs them): its reply says what each round did, and the seat kept presses less against
    its flat seat."""
    _, plain = _request(api, "POST", "/api/fit", SINGLE)
    status, reply = _request(api, "POST", "/api/fit", {**SINGLE, "relief": {"rounds": 1}})
    assert status == 200, reply
    assert plain["relief"] is None and reply["parameters"]["relief"]["rounds"] == 1
    rounds = reply["relief"]["rounds"]
    assert rounds and rounds[0]["round"] == 1 and reply["relief"]["stopped"] is False
    assert reply["relief"]["kept"] == 1, rounds  # (single_seated's first round is kept)
    assert reply["persons"][0]["peak_of_flat"] < plain["persons"][0]["peak_of_flat"] - 0.02
    assert reply["surface"] != plain["surface"]


def test_relax_relaxes_onto_the_relieved_surface_that_fit_answers_with(api):
    """/api/relax of a scenario with [relief] rounds relaxes onto the surface /api/fit answers
    with, relieved (as `sitrelax relax` does): its figures before are the fit's."""
    relieved = {**SINGLE, "relief": {"rounds": 1}}
    _, fit = _request(api, "POST", "/api/fit", relieved)
    assert fit["relief"]["kept"] == 1  # (else both would be the plain fit's)
    status, relaxed = _request(api, "POST", "/api/relax", {"scenario": relieved, "index": 0})
    assert status == 200, relaxed
    assert relaxed["surface"] == fit["surface"]
    before, figures = relaxed["before"], fit["persons"][0]
    for key in ("coverage", "contact_coverage", "max_penetration_m", "peak_pressure_kpa"):
        assert before[key] == pytest.approx(figures[key], abs=1e-9), key


def test_the_same_fit_sent_with_an_inline_control_mesh_gives_the_same_surface(api):
    _, grid_reply = _request(api, "POST", "/api/fit", SINGLE)
    inline = json.loads(json.dumps(SINGLE))
    del inline["surface"]["grid"]
    from solver.surface.subdivision import grid_mesh

    v, f = grid_mesh((0.5, 0.6), (8, 6), 0.42)
    inline["surface"]["control_mesh"] = {"vertices": v.tolist(), "faces": f.tolist()}
    status, reply = _request(api, "POST", "/api/fit", inline)
    assert status == 200, reply
    assert reply["surface"]["vertices"] == grid_reply["surface"]["vertices"]


def test_library_poses_are_listed_searched_and_used(api):
    status, reply = _request(api, "GET", "/api/poses?tags=high")
    assert status == 200 and [p["name"] for p in reply["poses"]] == ["perch"]
    assert reply["poses"][0]["take"] == "high_sit" and reply["poses"][0]["frame"] == 39
    status, reply = _request(api, "GET", "/api/poses")
    assert reply["total"] == 2
    status, reply = _request(api, "GET", "/api/poses/nobody")
    assert status == 404 and "nobody" in reply["detail"]
    # the library pose is the bundled frame 39: the same body comes back
    from_db = {"person": {**SINGLE["person"][0], "pose": "db:perch"}}
    _, a = _request(api, "POST", "/api/body", from_db)
    _, b = _request(api, "POST", "/api/body", {"person": SINGLE["person"][0]})
    assert len(a["vertices"]) == 13380
    assert abs(sum(map(sum, a["vertices"])) - sum(map(sum, b["vertices"]))) < 1e-3


@pytest.mark.slow  # the default run stays within its time
def test_pressure_evaluate_and_relax(api):
    person = SINGLE["person"][0]
    status, field = _request(api, "POST", "/api/pressure", {"person": person})
    assert status == 200 and field["vertices"] == len(field["importance"]) == 13380
    assert max(field["importance"]) == pytest.approx(1.0) and min(field["importance"]) == 0.0
    _, fit = _request(api, "POST", "/api/fit", SINGLE)
    status, ev = _request(api, "POST", "/api/evaluate",
                          {**fit["surface"], "person": [person]})
    assert status == 200
    assert ev["persons"][0]["coverage"] == pytest.approx(fit["persons"][0]["coverage"], abs=1e-6)
    # a floor two metres below supports nothing within the margin
    floor = {"vertices": [[-2, -2, -2], [-2, -2, 2], [2, -2, 2], [2, -2, -2]],
             "faces": [[0, 1, 2, 3]], "person": [person]}
    status, ev = _request(api, "POST", "/api/evaluate", floor)
    assert status == 200 and ev["persons"][0]["coverage"] == 0.0
    status, relaxed = _request(api, "POST", "/api/relax", {"scenario": SINGLE, "index": 0})
    assert status == 200 and len(relaxed["body"]["vertices"]) == 13380
    # relaxing is never worse by the evaluation's figures, and says what it accepted
    b, a = relaxed["before"], relaxed["after"]
    assert a["mean_support_distance_m"] <= b["mean_support_distance_m"]
    assert a["coverage"] >= b["coverage"] and a["contact_coverage"] >= b["contact_coverage"]
    assert a["max_penetration_m"] <= b["max_penetration_m"]
    assert relaxed["relaxation"]["steps"] and relaxed["relaxation"]["summary"]
    status, reply = _request(api, "POST", "/api/relax", {"scenario": SINGLE, "index": 3})
    assert status == 400 and "index" in reply["detail"]


@pytest.mark.parametrize("change, status, words", [
    ({"pose": "bvh:/etc/passwd#frame=0"}, 422, "got a BVH file: this server reads no files"),
    ({"pose": "bvh:bundled:../../etc/passwd#frame=0"}, 422, "got a path (the bundled ones "
                                                            "are at /api/recordings)"),
    ({"pose": "bvh:bundled:nobody.bvh#frame=0"}, 404, "No bundled recording 'nobody.bvh' "
                                                      "(the bundled ones are at /api/recordings)"),
    ({"pose": "db:nobody"}, 404, "nobody"),
    ({"position": [5.0, 0.0, 0.0]}, 400, "outside the surface's reach"),
    ({"support": ["wings"]}, 422, "support"),
    ({"colour": "red"}, 422, "colour"),
])
def test_bad_requests_get_a_4xx_that_names_the_problem(api, change, status, words):
    body = json.loads(json.dumps(SINGLE))
    body["person"][0].update(change)
    got, reply = _request(api, "POST", "/api/fit", body)
    assert got == status
    assert words in json.dumps(reply)


@pytest.mark.parametrize("change, status, words", [
    ({"pose": "db:nobody"}, 404, "No pose 'nobody' in the server's pose library"),
    ({"pose": "bvh:bundled:cmu_75_18_high_sit.bvh#frame=999"}, 400,
     "Expected a frame in 0..76 of bundled:cmu_75_18_high_sit.bvh, got 999"),
    ({"pose": "db:" + "x" * 120}, 404, "x" * 37 + "..."),
])
def test_errors_name_no_path_on_the_server_and_send_back_no_long_value(api, change, status,
                                                                       words):
    """The library's and the bundled recordings' paths are the server's business: an error
    names them as such or by the file's name; a long value sent is quoted shortened."""
    body = json.loads(json.dumps(SINGLE))
    body["person"][0].update(change)
    got, reply = _request(api, "POST", "/api/fit", body)
    assert got == status, reply
    [error] = reply["detail"]
    assert error["loc"] == ["body", "person", 0, "pose"] and words in error["msg"], reply
    assert "/" not in error["msg"] and "poses.h5" not in error["msg"]
    assert "x" * 41 not in error["msg"]


@pytest.mark.parametrize("pose, status, words", [
    ("db:nosuch", 404, "No pose 'nosuch' in the server's pose library"),
    ("bvh:bundled:cmu_75_18_high_sit.bvh#frame=99999", 400, "Expected a frame in 0..76"),
    ("bvh:bundled:nosuch.bvh#frame=0", 404, "No bundled recording 'nosuch.bvh'"),
])
@pytest.mark.parametrize("path", ["/api/fit", "/api/relax", "/api/body"])
def test_a_pose_that_cannot_be_loaded_is_refused_naming_its_field(api, path, pose, status,
                                                                  words):
    person = {**SINGLE["person"][0], "pose": pose}
    body, loc = {
        "/api/fit": ({**SINGLE, "person": [person]}, ["body", "person", 0, "pose"]),
        "/api/relax": ({"scenario": {**SINGLE, "person": [person]}},
                       ["body", "scenario", "person", 0, "pose"]),
        "/api/body": ({"person": person}, ["body", "person", "pose"])}[path]
    got, reply = _request(api, "POST", path, body)
    assert got == status, reply
    [error] = reply["detail"]
    assert error["loc"] == loc and words in error["msg"], reply


def test_evaluate_refuses_a_surface_facing_away_from_the_body(api):
    """A seat plane under the sitter's buttocks, its faces reversed (as Rhino may draw a plane
    seen from above), got figures of a surface that barely touches (contact 0.0099 against
    0.132 facing up, measured 2026-12-07); it is refused as a fit refuses such a control mesh.
    The same plane facing up passes the check."""
    from solver.contact.evaluate import facing_away_share
    from solver.mesh import SurfaceMesh
    from solver.scene.placement import place_scene
    from solver.scene.scenario import load_scenario

    _, (person,) = place_scene(load_scenario(_example_path("single_seated")))
    seat = float(person.vertices[person.importance > 0, 1].min()) + 0.01
    vertices = [[-1, seat, -1], [-1, seat, 1], [1, seat, 1], [1, seat, -1]]  # faces up
    up = SurfaceMesh.from_quads(vertices, [[0, 1, 2, 3]])
    down = SurfaceMesh.from_quads(vertices, [[3, 2, 1, 0]])
    assert facing_away_share(up, person) < 0.1 and facing_away_share(down, person) > 0.9
    status, reply = _request(api, "POST", "/api/evaluate",
                             {"vertices": vertices, "faces": [[3, 2, 1, 0]],
                              "person": [SINGLE["person"][0]]})
    assert status == 400
    assert re.match(r"person 1: the surface's faces point away from the body \(\d+% of the "
                    r"supported skin near it faces the same way as the surface\); flip the "
                    r"mesh", reply["detail"]), reply


def test_a_message_with_apostrophes_is_sent_whole(api):
    """Only a quoted value is shortened: the text between the apostrophes of "people's" and
    "person's" is the message's own."""
    body = json.loads(json.dumps(SINGLE))
    body["surface"].pop("grid", None)
    body["surface"]["template"] = {"kind": "bed"}
    got, reply = _request(api, "POST", "/api/fit", body)
    assert got == 400, reply
    assert "...'" not in reply["detail"] and "lowest point is 0.000 m above the floor, " \
        "leaving no room for a bed under them: lift them (each person's position y" \
        in reply["detail"], reply


def test_a_body_nested_too_deep_for_the_json_reader_is_malformed_422(api):
    for body in (b"[" * 100_000 + b"]" * 100_000, b'{"scenario": 1' + b"0" * 5000 + b"}"):
        got, reply = _request(api, "POST", "/api/fit", body)
        assert got == 422, (got, reply)
        assert reply["detail"][0]["loc"] == ["body"]
    assert _request(api, "GET", "/api/health")[0] == 200  # and the server goes on


def test_a_control_mesh_that_is_not_all_quads_is_refused(api):
    body = json.loads(json.dumps(SINGLE))
    del body["surface"]["grid"]
    body["surface"]["control_mesh"] = {"vertices": [[0, 0.4, 0], [1, 0.4, 0], [1, 0.4, 1],
                                                    [0, 0.4, 1]], "faces": [[0, 1, 2]]}
    status, _ = _request(api, "POST", "/api/fit", body)
    assert status == 422
    body["surface"]["control_mesh"]["faces"] = [[0, 1, 1, 3]]
    status, reply = _request(api, "POST", "/api/fit", body)
    assert status == 400 and "distinct" in reply["detail"]


def test_a_request_over_the_size_limit_gets_413(api):
    status, reply = _request(api, "POST", "/api/fit", b"[" + b"0," * 600_000 + b"0]")
    assert status == 413 and "limit" in reply["detail"]
    # without a Content-Length (chunked), the bytes are counted as they come
    conn = http.client.HTTPConnection(api.host, api.port, timeout=30)
    conn.putrequest("POST", "/api/fit")
    conn.putheader("Content-Type", "application/json")
    conn.putheader("Transfer-Encoding", "chunked")
    conn.endheaders()
    chunk = b"0," * 100_000
    try:
        for _ in range(12):
            conn.send(f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n")
        conn.send(b"0\r\n\r\n")
    except (BrokenPipeError, ConnectionResetError):
        pass  # the server may close before we finish sending
    response = conn.getresponse()
    assert response.status == 413
    conn.close()
    # a huge declared size and a client that then sends nothing: answered at once, not after
    # the body's 30 s pause
    conn = http.client.HTTPConnection(api.host, api.port, timeout=30)
    conn.putrequest("POST", "/api/fit")
    conn.putheader("Content-Type", "application/json")
    conn.putheader("Content-Length", "999999999")
    conn.endheaders()
    conn.send(b"[")
    start = time.monotonic()
    response = conn.getresponse()
    assert response.status == 413 and time.monotonic() - start < 5
    conn.close()


def test_the_api_listens_on_loopback_only_by_default(api):
    assert api.host == "127.0.0.1"
    assert listening_addresses(api.port) == {"127.0.0.1"}


def test_wider_addresses_are_flagged():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.10")
    assert exposure_warning("127.0.0.1", "API") is None
    assert "other machines" in exposure_warning("0.0.0.0", "API")


def test_the_serve_command_starts_on_loopback_and_stops(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "studio.cli", "serve", "--port", "0"],
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stderr.readline()
        m = re.search(r"listening on http://([\d.]+):(\d+)", line)
        assert m, line
        assert m[1] == "127.0.0.1" and listening_addresses(int(m[2])) == {"127.0.0.1"}
        conn = http.client.HTTPConnection(m[1], int(m[2]), timeout=10)
        conn.request("GET", "/openapi.json")
        spec = json.loads(conn.getresponse().read())
        assert {"/api/fit", "/api/poses", "/api/body", "/api/pressure", "/api/relax",
                "/api/evaluate"} <= set(spec["paths"])
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_serve_refuses_a_missing_library(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "studio.cli", "serve", "--db",
                           str(tmp_path / "none.h5"), "--port", "0"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and "none.h5" in proc.stderr


# the description as the server publishes it (it does not depend on the library)
fuzzed = schemathesis.openapi.from_dict(create_app(None).openapi())


@pytest.mark.slow
@fuzzed.parametrize()
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
def test_fuzzing_the_openapi_description_finds_no_server_error_and_no_hang(case, api):
    case.call_and_validate(base_url=api.url, checks=[not_a_server_error], timeout=60)


# the default run's smoke test: every operation, ten generated requests each (the schema's
# examples and a short fuzz, without the coverage phase's every boundary value)
quick = schemathesis.openapi.from_dict(
    create_app(None).openapi(),
    config=SchemathesisConfig.from_dict({"phases": {"coverage": {"enabled": False}}}))


@quick.parametrize()
@settings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck))
def test_a_short_fuzz_of_every_operation_finds_no_server_error(case, api):
    case.call_and_validate(base_url=api.url, checks=[not_a_server_error], timeout=60)


def test_a_warm_refit_goes_on_from_an_earlier_fit(api):
    """A fit names itself (`fit_id`); the same scenario with its person moved 2 cm, sent with
    `warm`, refits from that fit and settles in fewer iterations; an id the server does not
    keep is a 404, a fit of another control mesh a 400 that says so."""
    status, first = _request(api, "POST", "/api/fit", SINGLE)
    assert status == 200, first
    moved = json.loads(json.dumps(SINGLE))
    moved["person"][0]["position"][2] += 0.02
    status, cold = _request(api, "POST", "/api/fit", moved)
    assert status == 200, cold
    status, warm = _request(api, "POST", f"/api/fit?warm={first['fit_id']}", moved)
    assert status == 200, warm
    assert warm["stop_reason"].startswith("settled"), warm["stop_reason"]
    assert warm["iterations"] < cold["iterations"]
    # (tests/solver/surface/test_refit.py: 0.956 against 0.954 on this move, both over the bar)
    assert warm["persons"][0]["coverage"] >= cold["persons"][0]["coverage"] - 0.02
    assert warm["fit_id"] not in (first["fit_id"], cold["fit_id"])
    status, reply = _request(api, "POST", "/api/fit?warm=0123456789abcdef", moved)
    assert status == 404 and "fit without `warm`" in reply["detail"], reply
    other = json.loads(json.dumps(SINGLE))
    other["surface"]["grid"]["resolution"] = [6, 6]
    status, reply = _request(api, "POST", f"/api/fit?warm={first['fit_id']}", other)
    assert status == 400 and "same control mesh" in reply["detail"], reply
    status, reply = _request(api, "POST", "/api/fit?warm=not-an-id", moved)
    assert status == 422, reply
