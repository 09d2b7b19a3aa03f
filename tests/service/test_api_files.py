"""The dashboard's files (GET / and /static/...) are served from the list made at start, by name: no request value
becomes a file path, so no traversal, encoded or not, and no symlink out of the folder reaches another file."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from frictionwatch.service.api import create_app


@pytest.fixture
def client(tmp_path):
    root = tmp_path / "dashboard"
    (root / "static" / "vendor").mkdir(parents=True)
    (root / "index.html").write_text("<html>fw</html>")
    (root / "static" / "app.js").write_text("console.log('fw')")
    (root / "static" / "vendor" / "lib.js").write_text("lib")
    (tmp_path / "secret.txt").write_text("SECRET")
    (root / "static" / "leak.txt").symlink_to(tmp_path / "secret.txt")
    with TestClient(create_app([], token=None, dashboard_dir=root)) as c:
        yield c


def test_page_and_static_files(client) -> None:
    assert client.get("/").text == "<html>fw</html>"
    assert client.get("/static/app.js").text == "console.log('fw')"
    assert client.get("/static/vendor/lib.js").text == "lib"


@pytest.mark.parametrize("path", ["/static/leak.txt", "/static/../secret.txt", "/static/..%2F..%2Fsecret.txt",
                                  "/static/%2e%2e/%2e%2e/secret.txt", "/static//etc/passwd", "/static/index.html",
                                  "/static/vendor/../../secret.txt"])
def test_nothing_outside_the_list(client, path: str) -> None:
    r = client.get(path)
    assert r.status_code == 404 and "SECRET" not in r.text and "root:" not in r.text


def test_no_dashboard_installed(tmp_path) -> None:
    with TestClient(create_app([], dashboard_dir=tmp_path / "absent")) as c:
        r = c.get("/")
        assert r.status_code == 404 and "not installed" in r.json()["detail"]


def test_state_changes_without_a_configured_token_are_refused(tmp_path) -> None:
    with TestClient(create_app([], token=None, dashboard_dir=tmp_path)) as c:
        assert c.post("/api/v1/engines/any/baseline", headers={"Authorization": "Bearer x"}).status_code == 401
