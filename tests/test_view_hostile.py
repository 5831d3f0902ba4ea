"""The inspector's server under hostile requests (issue 33): every request a client can make
wrongly gets a 4xx with one line, never a 500, and the server keeps serving after it;
concurrent saves of one name never overwrite each other silently."""

from __future__ import annotations

import http.client
import json
import os
import socket
import threading

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from test_view_server import Server, folder, server  # noqa: F401 (fixtures: a copy of the demo per module)


def raw(server: Server, method: str, target: bytes, *, body: bytes | None = None,
        token: bytes | None = None) -> tuple[int, bytes]:
    """(status, body) of a request sent byte for byte (no client-side quoting or encoding)."""
    host, port = server.base.removeprefix("http://").rsplit(":", 1)
    head = [method.encode() + b" " + target + b" HTTP/1.1", f"Host: {host}:{port}".encode(),
            b"X-Pxr-Token: " + (token if token is not None else server.token.encode()), b"Connection: close"]
    if body is not None:
        head += [b"Content-Type: application/json", f"Content-Length: {len(body)}".encode()]
    with socket.create_connection((host, int(port)), timeout=120) as connection:
        try:
            connection.sendall(b"\r\n".join(head) + b"\r\n\r\n" + (body or b""))
        except (BrokenPipeError, ConnectionResetError):  # answered (413) before the whole body was read
            pass
        response = http.client.HTTPResponse(connection)
        response.begin()
        return response.status, response.read()


def one_line_4xx(status: int, body: bytes, *expected: int) -> None:
    assert 400 <= status < 500 and (not expected or status in expected), (status, body)
    answer = json.loads(body)
    assert set(answer) <= {"error", "position"} and "\n" not in answer["error"], answer


def still_serving(server: Server) -> None:
    status, body, _ = server.request("/api/session")
    assert status == 200, body
    assert server.request("/api/check", {"expression": "C.*"})[0] == 200


# --- the folder's files ------------------------------------------------------------------------


def test_a_symlink_loop_in_the_folder(server, folder):
    os.symlink("loop_a", folder / "loop_b")
    os.symlink("loop_b", folder / "loop_a")
    os.symlink("self", folder / "self")
    for name in ("loop_a", "self", "self/x", "loop_b/deeper"):
        status, body, _ = server.request(f"/files/{name}")
        one_line_4xx(status, body, 403, 404)
        still_serving(server)


@pytest.mark.parametrize("name", ["a" * 300, "a" * 300 + "/b", "d/" * 2100 + "x", "é" * 200])
def test_over_long_file_names(server, name):
    status, body, _ = server.request("/files/" + name.replace("é", "%C3%A9"))
    assert status in (403, 404, 414), (status, body)
    still_serving(server)


@pytest.mark.parametrize("target", [b"/files/%ff%fe", b"/files/\xff\xfe.png", b"/files/a%00b", b"/api/image/%ff",
                                    b"/api/image/\xc3", b"/api/inspect?x0=%ff&y0=0&x1=1&y1=1"])
def test_invalid_utf8_paths(server, target):
    status, body = raw(server, "GET", target)
    assert 400 <= status < 500, (target, status, body)
    still_serving(server)


@pytest.mark.parametrize("token", [b"\xff\xfe", b"\xc3", "é".encode() * 16, b"x" * 5000])
def test_invalid_utf8_tokens(server, token):
    status, body = raw(server, "GET", b"/api/session", token=token)
    assert status in (400, 403), (token, status, body)
    still_serving(server)


# --- bodies ------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", ["/api/check", "/api/layer", "/api/save", "/api/suggest", "/api/generalise"])
@pytest.mark.parametrize("body", [b"[" * 100_000 + b"]" * 100_000, b'{"a":' * 50_000 + b"1" + b"}" * 50_000,
                                  b"\xff\xfe{}", b'{"expression": "\xff"}', b"", b"null", b"{" * 10,
                                  b'{"k": 1e999999}', b'{"k": ' + b"9" * 5000 + b"}", b'{"name": NaN}'])
def test_malformed_bodies(server, path, body):
    status, answer = raw(server, "POST", path.encode(), body=body)
    one_line_4xx(status, answer)
    still_serving(server)


def test_an_over_large_body(server):
    status, answer = raw(server, "POST", b"/api/check", body=b'{"expression": "' + b"C" * (2 << 20) + b'"}')
    assert status == 413, (status, answer)
    still_serving(server)


# --- ids, grades, names ------------------------------------------------------------------------


@pytest.mark.parametrize("entry", [{"id": ["x"]}, {"id": {"a": 1}}, {"id": 12}, {"id": None}, {"id": "nope"},
                                   {"id": "x" * 10_000}, {}, {"id": "diffuse_direct", "tint": "rgb"},
                                   {"id": "diffuse_direct", "tint": [1, 2]}, {"id": "diffuse_direct", "tint": None}])
def test_unknown_or_malformed_layer_ids(server, entry):
    status, answer, _ = server.request("/api/save", {"name": "bad_ids", "layers": [entry]})
    one_line_4xx(status, answer, 400, 404)
    still_serving(server)


@pytest.mark.parametrize("grade", [{"stops": 10 ** 400}, {"stops": 1e308}, {"stops": -1e308}, {"stops": "1e999"},
                                   {"stops": "nan"}, {"tint": [10 ** 400, 1, 1]}, {"tint": [1e308, 1e308, 1e308]},
                                   {"tint": ["inf", 1, 1]}, {"stops": 1000}, {"tint": [-1, 1, 1]}])
def test_grades_that_overflow(server, grade):
    status, answer, _ = server.request("/api/save", {"name": "overflow", "layers": [{"id": "diffuse_direct", **grade}]})
    one_line_4xx(status, answer, 400)
    still_serving(server)


@pytest.mark.parametrize("exposure", [10 ** 400, 1e308, -1e308, 1e6])
def test_exposures_that_overflow(server, exposure):
    status, answer, _ = server.request("/api/save", {"name": "overflow", "exposure": exposure,
                                                     "layers": [{"id": "diffuse_direct"}]})
    one_line_4xx(status, answer, 400)
    still_serving(server)


@pytest.mark.parametrize("name", ["a" * 300, "a" * 250, "b" * 100_000])
def test_over_long_save_names(server, folder, name):
    status, answer, _ = server.request("/api/save", {"name": name, "layers": [{"id": "diffuse_direct"}]})
    one_line_4xx(status, answer, 400)
    assert not list(folder.glob("aaaa*"))
    still_serving(server)


@pytest.mark.parametrize("name", ["a" * 300, "x" * 100_000, "é"])
def test_over_long_layer_names(server, name):
    status, answer, _ = server.request("/api/layer", {"name": name, "expression": "C.*"})
    one_line_4xx(status, answer, 400)
    still_serving(server)


# --- concurrent saves ------------------------------------------------------------------------------


def test_concurrent_saves_of_one_name_do_not_overwrite_each_other(server, folder):
    stacks = [[{"id": "diffuse_direct", "stops": 1.0}], [{"id": "glossy_direct", "stops": 2.0}]]
    answers: list[int] = [0, 0]

    def save(i: int) -> None:
        answers[i] = server.request("/api/save", {"name": "race", "layers": stacks[i]})[0]

    threads = [threading.Thread(target=save, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(answers) == [200, 409], answers
    winner = stacks[answers.index(200)][0]["id"]
    assert winner in (folder / "race.nk").read_text()
    assert server.request("/api/save", {"name": "race", "layers": stacks[1]})[0] == 409
    again = server.request("/api/save", {"name": "race", "layers": stacks[1], "overwrite": True})
    assert again[0] == 200 and "glossy_direct" in (folder / "race.nk").read_text()


def test_overwrite_must_be_a_boolean(server):
    status, answer, _ = server.request("/api/save", {"name": "race2", "layers": [{"id": "diffuse_direct"}],
                                                     "overwrite": "no"})
    one_line_4xx(status, answer, 400)


# --- anything at all -------------------------------------------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=40),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=10), children, max_size=4),
    max_leaves=12)
known_keys = st.sampled_from(["name", "expression", "layers", "exposure", "overwrite", "k", "classes", "keep",
                              "id", "stops", "tint", "mute", "solo"])
bodies = st.one_of(json_values, st.dictionaries(known_keys, json_values, max_size=5),
                   st.fixed_dictionaries({"name": st.text(max_size=300), "layers": st.lists(
                       st.dictionaries(known_keys, json_values | st.sampled_from(["diffuse_direct", "beauty"]),
                                       max_size=4), max_size=3)}))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(path=st.sampled_from(["/api/check", "/api/layer", "/api/save", "/api/suggest", "/api/generalise"]),
       body=bodies)
def test_no_json_body_is_an_internal_error(server, path, body):
    if path == "/api/suggest" and isinstance(body, dict):
        body = {**body, "k": 99}  # no long suggestion
    data = json.dumps(body).encode()
    status, answer = raw(server, "POST", path.encode(), body=data)
    assert status != 500 and status < 500, (path, body, answer)
