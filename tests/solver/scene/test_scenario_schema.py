"""One scenario schema: the same scenario as a TOML file, as the HTTP API's JSON and built in
the studio gives the same fit parameters, people and report parameters."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from solver.scene import schema
from solver.scene.run import report_parameters, run_fit
from solver.scene.scenario import load_scenario, parse_scenario
from studio.api import create_app, request_scenario
from studio.design import Design

POSE = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


@pytest.fixture(scope="module")
def client():
    with TestClient(create_app(None), base_url="http://127.0.0.1") as c:
        yield c


def _studio() -> Design:
    d = Design(None)
    d.new_grid((0.5, 0.6), (8, 6), 0.42)
    d.set_fixed(0, True)
    for name, value in (("level", 2.0), ("sigma", 0.004), ("tau_max", 0.4), ("margin", 0.025)):
        d.set_parameter(name, value)
    d.add_person(POSE, name="sitter", position=[0.0, 0.0, -0.1], support=["legs"])
    return d


def _toml(vertices: list, faces: list) -> str:
    return f"""
[surface]
control_mesh = {{ vertices = {json.dumps(vertices)}, faces = {json.dumps(faces)} }}
level = 2
sigma = 0.004
tau_max = 0.4
margin = 0.025
fixed = [0]

[[person]]
name = "sitter"
pose = "{POSE}"
position = [0.0, 0.0, -0.1]
support = ["legs"]
"""


def test_the_same_scenario_as_toml_as_api_json_and_in_the_studio_fits_alike(client, tmp_path):
    studio = _studio()
    vertices, faces = studio.vertices.tolist(), studio.faces.tolist()
    path = tmp_path / "same.toml"
    path.write_text(_toml(vertices, faces))
    request = {"surface": {"control_mesh": {"vertices": vertices, "faces": faces}, "level": 2,
                           "sigma": 0.004, "tau_max": 0.4, "margin": 0.025, "fixed": [0]},
               "person": [{"name": "sitter", "pose": POSE, "position": [0.0, 0.0, -0.1],
                           "support": ["legs"]}]}
    from_toml, from_studio = load_scenario(path), studio.scenario()
    from_api = request_scenario(schema.Scenario.model_validate(request))
    assert from_toml.surface.params == from_api.surface.params == from_studio.surface.params
    assert from_toml.persons == from_api.persons == from_studio.persons
    report = run_fit(from_toml, tmp_path / "out")
    reply = client.post("/api/fit", json=request)
    assert reply.status_code == 200, reply.text
    stored = json.loads((tmp_path / "out" / "report.json").read_text())["parameters"]
    assert reply.json()["parameters"] == stored == report["parameters"]
    assert report_parameters(from_studio) == stored
    assert stored["control_mesh"] == "inline control mesh, 63 vertices, 48 quads"


def test_what_is_left_out_has_the_same_default_everywhere():
    pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
    from_toml = parse_scenario({"surface": {"grid": {}}, "person": [{"pose": pose}]})
    from_api = request_scenario(schema.Scenario.model_validate(
        {"surface": {"grid": {}}, "person": [{"pose": pose}]}))
    studio = Design(None)
    studio.add_person(pose, name="person 1")
    from_studio = studio.scenario()
    assert from_toml.surface.params == from_api.surface.params == from_studio.surface.params
    assert from_toml.surface.params.sigma == 0.003
    assert from_toml.persons == from_api.persons == from_studio.persons
    assert from_toml.persons[0].position == (0.0, 0.0, 0.0)
    assert schema.default(schema.Person, "support") == "seat"
    assert from_toml.persons[0].support == ("pelvis", "thighs")  # a seat's regions
    assert from_toml.foam_stiffness == from_studio.foam_stiffness == 200.0
    assert (from_toml.surface.vertices == from_studio.surface.vertices).all()
    assert from_toml.surface.source == "grid 8x6, 1.2 x 0.8 m at 0.45 m"


@pytest.mark.parametrize("support, regions", [
    ("chair", ("upper_back", "lower_back", "pelvis", "thighs")),
    (["torso", "legs"], ("upper_back", "lower_back", "pelvis", "thighs", "calves")),
    (["seat", "calves", "Thighs"], ("pelvis", "thighs", "calves")),
])
def test_a_support_is_expanded_to_regions_alike_from_toml_api_and_studio(support, regions):
    import tomllib

    from solver.scene.scenario import scenario_toml

    data = {"surface": {"grid": {}}, "person": [{"pose": POSE, "support": support}]}
    from_toml = parse_scenario(tomllib.loads(scenario_toml(data)))
    from_api = request_scenario(schema.Scenario.model_validate(data))
    studio = Design(None)
    studio.add_person(POSE, name="person 1", support=support)
    assert from_toml.persons[0].support == from_api.persons[0].support == regions
    assert studio.scenario().persons[0].support == regions
    assert studio.scenario_data()["person"][0]["support"] == support  # kept as written


@pytest.mark.parametrize("support, message", [
    (["tail"], r"person\[0\]\.support: expected body regions \(head, upper_back, .*\), "
               r"parts \(torso, arms, legs\) or uses \(seat, .*\), got 'tail'"),
    ("sofa", "got 'sofa'"),
    ([], r"person\[0\]\.support: expected at least one body region or a use"),
    (3, r"person\[0\]\.support: expected a use name or a list of body regions, got 3"),
])
def test_a_bad_support_names_the_field_and_what_it_takes(support, message):
    from solver.scene.scenario import ScenarioError

    data = {"surface": {"grid": {}}, "person": [{"pose": POSE, "support": support}]}
    with pytest.raises(ScenarioError, match=message):
        parse_scenario(data, "s.toml")


def _request(**surface) -> dict:
    return {"surface": {"grid": {"size": [0.5, 0.6], "height": 0.42}, "level": 2,
                        "max_iterations": 3, **surface},
            "person": [{"pose": POSE, "position": [0.0, 0.0, -0.1], "support": ["legs"]}]}


def test_creases_and_every_fit_parameter_go_through_the_api(client):
    reply = client.post("/api/fit", json=_request(creases=[[0, 1], [1, 2]], anchor=0.002,
                                                  pull_range=0.3, step=0.04))
    assert reply.status_code == 200, reply.text
    parameters = reply.json()["parameters"]
    assert parameters["creases"] == [[0, 1], [1, 2]]
    assert (parameters["anchor"], parameters["pull_range"], parameters["step"]) == (
        0.002, 0.3, 0.04)
    assert parameters["sigma"] == 0.003  # the schema's default, as in a TOML file
    reply = client.post("/api/fit", json=_request(creases=[[0, 99]]))
    assert reply.status_code == 400
    assert "surface.creases[0]: expected a whole number in 0..62, got 99" in reply.json()["detail"]


@pytest.mark.parametrize("surface, words", [
    ({"level": 4}, "at most 3 here"),
    ({"max_iterations": 500}, "at most 100 here"),
    ({"grid": {"resolution": [60, 60]}}, "at most 2000 control vertices"),
])
def test_the_server_s_own_bounds_are_limits_that_name_the_field(client, surface, words):
    reply = client.post("/api/fit", json=_request(**surface))
    assert reply.status_code == 422
    assert words in reply.text


def test_too_many_people_are_refused_by_the_server(client):
    request = _request()
    request["person"] = request["person"] * 7
    reply = client.post("/api/fit", json=request)
    assert reply.status_code == 422 and "at most 6 people" in reply.text
