"""Every route of the API, walked with wrong names, wrong ids, ids of another kind and bad bodies, answers a 4xx with
the JSON error body, never a 500 (issue 12: the server survives careless and hostile input).

The routes are read from ``app.routes``, so a new route is walked without being listed here. Each route is called
once with values that exist in the demo session (a baseline that must not be a 500) and then with one path
parameter, query parameter or body field at a time swapped for a wrong value, which must be a 4xx.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import httpx
import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute, iter_route_contexts
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.calib.sweep.service import KIND as SWEEP_KIND
from tests.conftest import fresh_demo, wait_job

WRONG_NAMES = ["nope", "..", "a" * 300, "x\x00y", "%2e%2e"]
"""Names and ids that exist nowhere: missing, traversal, too long, a NUL byte."""


class Walk:
    """A demo session with results of two kinds, and the values a route's parameters take from it."""

    def __init__(self, client: TestClient, root: Path):
        self.client = client
        self.root = root
        """The sessions folder, which no answer may name."""
        session = client.get("/api/sessions/demo").json()
        self.sensors: list[str] = session["sensors"]
        manual = client.post("/api/sessions/demo/lidar-camera/manual", json={
            "camera": "cam_front", "lidar": "lidar_top",
            "pose": {"xyz_m": [0.1, 0.0, 0.0], "ypr_deg": [0.0, 0.0, 0.0]}})
        assert manual.status_code == 201, manual.text
        results = client.get("/api/sessions/demo/results").json()
        self.result_ids = sorted({r["id"] for r in results})
        self.owners: dict[str, tuple[str, str]] = {r["id"]: (r["sensor"], r["kind"]) for r in results}
        """Each result's sensor and kind."""
        assert {r["kind"] for r in results} >= {"intrinsics", "lidar_camera"}, results
        self.capture_ids: list[str] = []
        for sensor in self.sensors:
            listed = client.get(f"/api/sessions/demo/sensors/{sensor}/captures").json()
            self.capture_ids += [c["id"] for c in listed[:1]]
        assert len(self.capture_ids) >= 2, "the demo holds image and cloud captures"

    def candidates(self, field: str) -> tuple[list[Any], list[Any]]:
        """``(existing, wrong)`` values for a parameter or body field named ``field``."""
        sensors, captures, results = self.sensors, self.capture_ids, self.result_ids
        if field == "name":
            return ["demo"], WRONG_NAMES
        if field == "new_name":  # a session or sensor to create: only invalid names, so the walk creates nothing
            return [], WRONG_NAMES[1:]
        if field in ("sensor", "camera", "lidar", "source", "target"):
            return sensors, WRONG_NAMES
        if field in ("capture_id", "image_id", "cloud_id"):
            return captures, WRONG_NAMES
        if field == "result_id":
            return results, WRONG_NAMES
        if field in ("image_ids", "capture_ids", "set_names"):
            return [captures[:1]], [["nope"], [1], "nope"]
        if field == "cameras":
            return [sensors[:2]], [["nope", "also-nope"], [sensors[0]], "nope", []]
        if field == "pairs":
            return [[captures[:2]]], [[["nope", "nope"]], [["a"]], "nope"]
        if field == "topics":
            return [{sensors[0]: "/camera/image"}], [{"nope": "/x"}, "nope"]
        if field == "path":
            return ["/nonexistent/run.mcap"], ["/etc/passwd", "", "\x00"]
        if field == "device":
            return [{"driver": "nope"}], [{"driver": None}, "nope", {"driver": "rosbag"}]
        if field == "file_name":
            return ["overlay_before.jpg"], ["nope.jpg", "../session.json", "x\x00.jpg"]
        if field in ("job_id", "removal"):
            return ["nope"], WRONG_NAMES
        if field == "fmt":
            return ["camera_info"], ["nope"]
        if field in ("pose", "init"):
            return [{"xyz_m": [0.0, 0.0, 0.0], "ypr_deg": [0.0, 0.0, 0.0]}], [{"xyz_m": [0.0]}, "nope",
                                                                            {"ypr_deg": ["a", 0, 0]}]
        if field in ("xyz_m", "ypr_deg", "init_xyz_m", "init_ypr_deg"):
            return [[0.0, 0.0, 0.0]], [[0.0], ["a", 0, 0], "1,2"]
        if field == "range_m":
            return ["0.5,50"], ["50,0.5", "a,b", "nan,1"]
        if field == "parent":
            return ["base_link"], WRONG_NAMES
        if field == "mount_sigma":
            return [[0.01, 1.0]], [[0.0, 1.0], [-1.0, 1.0], "nope", [0.01]]
        if field == "board":
            return ["checkerboard:9x6:0.025"], ["nope", "checkerboard:0x0:0"]
        return [], []


@dataclass
class Operation:
    """One route as the OpenAPI document describes it: what a caller can vary."""

    method: str
    path: str
    path_params: list[str]
    query_params: list[tuple[str, bool]]
    """``(name, required)``."""
    body: str
    """'json', 'multipart' or '' (none)."""
    fields: list[str] = field(default_factory=list)
    """The JSON body's fields, or the multipart form's non-file fields."""
    files: list[str] = field(default_factory=list)
    """The multipart form's file fields."""

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def _operations(app: FastAPI) -> list[Operation]:
    """Every operation of ``app``'s OpenAPI document (every route of the API: see test_every_route_is_walked)."""
    schema = app.openapi()
    components = schema.get("components", {}).get("schemas", {})
    operations = []
    for path, methods in schema["paths"].items():
        for method, spec in methods.items():
            params = spec.get("parameters", [])
            content = spec.get("requestBody", {}).get("content", {})
            body, fields, files = "", [], []
            for media, kind in (("application/json", "json"), ("multipart/form-data", "multipart")):
                if media in content:
                    body = kind
                    model = components[content[media]["schema"]["$ref"].rsplit("/", 1)[1]]
                    for name, prop in model["properties"].items():
                        is_file = "contentMediaType" in prop or "contentMediaType" in prop.get("items", {})
                        (files if is_file else fields).append(name)
            operations.append(Operation(
                method.upper(), path, [p["name"] for p in params if p["in"] == "path"],
                [(p["name"], p.get("required", False)) for p in params if p["in"] == "query"], body, fields, files))
    return operations


_NO_BODY = object()


def _call(walk: Walk, op: Operation, path: dict[str, Any], query: dict[str, Any], body: Any) -> httpx.Response:
    # dots encoded too, so '..' reaches the server as a name instead of being resolved by the client
    url = op.path.format(**{k: quote(str(v), safe="").replace(".", "%2E") for k, v in path.items()})
    if body is _NO_BODY:
        return walk.client.request(op.method, url, params=query)
    if isinstance(body, bytes):
        return walk.client.request(op.method, url, params=query, content=body,
                                   headers={"Content-Type": "application/json"})
    if isinstance(body, Multipart):
        return walk.client.request(op.method, url, params=query, files=body.files, data=body.data)
    return walk.client.request(op.method, url, params=query, json=body)


@dataclass
class Multipart:
    files: list[tuple[str, tuple[str, bytes, str]]]
    data: dict[str, Any]


def _problem(response: httpx.Response, want_4xx: bool, private: str) -> str | None:
    """What is wrong with an answer: a 5xx, a 2xx where a 4xx was due, a 4xx without the JSON error body, or one
    naming the ``private`` path (where the server keeps its sessions)."""
    if response.status_code >= 500:
        return f"{response.status_code}: {response.text[:300]}"
    if want_4xx and not 400 <= response.status_code < 500:
        return f"{response.status_code} where a 4xx was due: {response.text[:200]}"
    if 400 <= response.status_code < 500:
        try:
            error = response.json()["error"]
        except (ValueError, KeyError, TypeError):
            return f"{response.status_code} without the JSON error body: {response.text[:200]}"
        if set(error) != {"message", "input"} or not error["message"]:
            return f"{response.status_code} with a malformed error body: {error}"
        if private in response.text:
            return f"{response.status_code} naming the server's sessions folder: {error}"
    return None


def _multipart(op: Operation, walk: Walk, swap: tuple[str, Any] | None) -> Multipart:
    files, data = [], {}
    for name in op.files:
        file_name = swap[1] if swap and swap[0] == f"{name}:filename" else "upload.bin"
        content = swap[1] if swap and swap[0] == f"{name}:content" else b"not an image or a cloud"
        files.append((name, (file_name, content, "application/octet-stream")))
    for name in op.fields:
        existing, _ = walk.candidates(name)
        data[name] = swap[1] if swap and swap[0] == name else (existing or ["x"])[0]
    return Multipart(files, data)


def _field_role(op: Operation, name: str) -> str:
    """The candidates' name for a body field: a ``name`` in a body is a session or sensor to create."""
    return "new_name" if name == "name" else name


def _json_body(op: Operation, walk: Walk, swap: tuple[str, Any] | None) -> dict[str, Any]:
    body = {}
    for name in op.fields:
        existing, _ = walk.candidates(_field_role(op, name))
        if existing:
            body[name] = existing[0]
    if swap:
        body[swap[0]] = swap[1]
    return body


ROUTE_KINDS = {"/intrinsics/": "intrinsics", "/lidar-lidar/": "lidar_lidar", "/lidar-camera/": "lidar_camera",
               "/sweep/": SWEEP_KIND, "/multicam/": "multicam"}
"""The kind of result a route's ``result_id`` must name, by a part of its path."""


def _route_kind(op: Operation) -> str | None:
    return next((kind for part, kind in ROUTE_KINDS.items() if part in op.path), None)


def _cases(op: Operation, walk: Walk) -> Iterator[tuple[str, dict, dict, Any, bool]]:
    """``(label, path, query, body, a 4xx is due)`` for one route: the baseline, then one value swapped at a time."""
    path = {n: (walk.candidates(n)[0] or ["x"])[0] for n in op.path_params}
    query = {n: walk.candidates(n)[0][0] for n, required in op.query_params if required and walk.candidates(n)[0]}
    if "preview" in dict(op.query_params):  # an edit or removal only previewed: later routes see the demo's sensors
        query["preview"] = True

    def body(swap: tuple[str, Any] | None = None) -> Any:
        if op.body == "json":
            return _json_body(op, walk, swap)
        if op.body == "multipart":
            return _multipart(op, walk, swap)
        return _NO_BODY

    yield "baseline", path, query, body(), False
    for name in op.path_params:
        existing, wrong = walk.candidates(name)
        for value in existing[1:]:
            yield f"path {name}={value!r}", path | {name: value}, query, body(), False
        for value in wrong:
            yield f"path {name}={value!r}", path | {name: value}, query, body(), True
    for name, required in op.query_params:
        existing, wrong = walk.candidates(name)
        for value in existing[1:]:
            yield f"query {name}={value!r}", path, query | {name: value}, body(), False
        for value in wrong or ["-1", "a" * 300]:
            # an optional filter naming nothing may list nothing: there no 5xx is all that is due
            yield f"query {name}={value!r}", path, query | {name: value}, body(), required and bool(wrong)
    # each result with its own sensor, so the kind is what is wrong: only the route's own kind may be accepted
    result_in = "body" if "result_id" in op.fields else "query" if "result_id" in dict(op.query_params) else None
    owner_param = next((n for n in ("sensor", "lidar") if n in op.path_params or n in dict(op.query_params)), None)
    if result_in and owner_param:
        for result_id, (sensor, kind) in walk.owners.items():
            where = {owner_param: sensor}
            case_path = path | where if owner_param in op.path_params else path
            case_query = query | where if owner_param not in op.path_params else query
            case_body = body(("result_id", result_id)) if result_in == "body" else body()
            if result_in == "query":
                case_query = case_query | {"result_id": result_id}
            due = _route_kind(op) not in (None, kind)
            yield f"{kind} result {result_id} of {sensor}", case_path, case_query, case_body, due
    if op.body == "json":
        for junk in (b"{not json", b"", json.dumps([1, 2]).encode(), json.dumps("x").encode()):
            yield f"body {junk!r}", path, query, junk, True
        yield "body with every field of a wrong type", path, query, {f: {"x": [1]} for f in op.fields}, True
        for name in op.fields:
            existing, wrong = walk.candidates(_field_role(op, name))
            for value in existing[1:]:
                yield f"body {name}={value!r}", path, query, body((name, value)), False
            for value in wrong:
                yield f"body {name}={value!r}", path, query, body((name, value)), True
    elif op.body == "multipart":
        for name in op.files:
            for value in ("x\x00.png", "../../etc/passwd", "a" * 300 + ".pcd"):
                yield f"upload {name} named {value!r}", path, query, body((f"{name}:filename", value)), True
            yield f"upload {name} empty", path, query, body((f"{name}:content", b"")), True
        for name in op.fields:
            for value in walk.candidates(name)[1]:
                yield f"form {name}={value!r}", path, query, body((name, value)), True
        yield "no files", path, query, Multipart([], {}), True


@pytest.fixture(scope="module")
def walk(demo_template: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Walk]:
    sessions = fresh_demo(demo_template, tmp_path_factory.mktemp("walk") / "sessions")
    app = create_app(sessions)
    with TestClient(app, raise_server_exceptions=False) as client:
        yield Walk(client, sessions.resolve())
    app.state.studio.jobs.shutdown()


def _app_operations() -> tuple[FastAPI, list[Operation]]:
    with tempfile.TemporaryDirectory() as empty:
        app = create_app(Path(empty))
    return app, [op for op in _operations(app) if op.path.startswith("/api/")]


@pytest.mark.slow
@pytest.mark.parametrize("op", _app_operations()[1], ids=str)
def test_route_answers_4xx_never_500(walk: Walk, op: Operation) -> None:
    problems = []
    for label, path, query, body, want_4xx in _cases(op, walk):
        response = _call(walk, op, path, query, body)
        if response.status_code == 202:
            # A job started. With a wrong value it may refuse it in the background: the job must then fail with an
            # error that names it (what polling /api/jobs/{id} shows), rather than run or vanish.
            if not want_4xx:
                walk.client.post(f"/api/jobs/{response.json()['id']}/cancel")
            else:
                status = wait_job(walk.client, response.json()["id"], timeout_s=60)
                if status["state"] != "failed" or not status["error"]:
                    problems.append(f"{label}: 202 and a job that ended {status['state']} ({status['error']})")
                continue
        if (problem := _problem(response, want_4xx, str(walk.root))) is not None:
            problems.append(f"{label}: {problem}")
    assert not problems, "\n".join(problems)


def test_every_route_is_walked() -> None:
    """The walk's operations are every API route of ``app.routes``, and each path parameter has wrong values."""
    app, operations = _app_operations()
    routes = {(method, ctx.path) for ctx in iter_route_contexts(app.routes) if isinstance(ctx.original_route, APIRoute)
              and ctx.path.startswith("/api/") for method in ctx.original_route.methods}
    assert len(routes) >= 40
    assert {(op.method, op.path) for op in operations} == routes
    walk = Walk.__new__(Walk)
    walk.sensors, walk.capture_ids, walk.result_ids = ["a", "b"], ["c1", "c2"], ["r1"]
    assert all(walk.candidates(name)[1] for op in operations for name in op.path_params)


@pytest.mark.parametrize(("path", "body", "input"), [
    ("/api/sessions/demo/sensors/cam_wide/intrinsics/solve", {"capture_ids": ["nope"]}, "capture_ids"),
    ("/api/sessions/demo/multicam/capture", {"cameras": ["cam_front", "nope"]}, "sensor"),
    ("/api/sessions/demo/lidar-camera/capture", {"camera": "cam_front", "lidar": "nope"}, "sensor"),
    ("/api/sessions/demo/sensors/lidar_top/import", {"device": {"driver": "rosbag", "topic": "/points"}}, "path"),
    ("/api/sessions/demo/sensors/lidar_top/import", {"device": {"driver": "rosbag", "path": "/no/such.mcap"}},
     "/no/such.mcap"),
])
def test_a_job_route_refuses_a_wrong_value_before_queueing(walk: Walk, path: str, body: dict, input: str,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A wrong id or a missing recording is a 4xx naming it at once, not a 202 and a job that fails later."""
    def no_job(*args: Any, **kwargs: Any) -> None:
        raise AssertionError(f"a job was queued for {path}")

    monkeypatch.setattr(walk.client.app.state.studio.jobs, "submit", no_job)
    response = walk.client.post(path, json=body)
    assert 400 <= response.status_code < 500, response.text
    assert response.json()["error"]["input"] == input, response.text
