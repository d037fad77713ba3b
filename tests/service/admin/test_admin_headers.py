"""The dashboard's security headers and form-post origin checks (issue 70): a
Content-Security-Policy and X-Frame-Options on every /admin response, pages that load nothing the
policy refuses, posts refused by their Referer when they carry no Origin, and a sign-out that
keeps SameSite=Strict."""

from __future__ import annotations

from html.parser import HTMLParser

import pytest

from app.service.admin.headers import content_security_policy, tile_source
from app.service.db.models import JourneyRow
from app.service.db.session import session_scope
from tests.utils.results.dashboard_seed import add_journey
from tests.utils.stack import ADMIN_KEY, sqlite_stack

TILES = "https://{s}.tiles.example.org/{z}/{x}/{y}.png"


@pytest.fixture
def stack(tmp_path):
    return sqlite_stack(tmp_path / "data", map_tile_url=TILES)


@pytest.fixture
def client(stack):
    with stack.client() as client:
        yield client


def _signed_in(client) -> None:
    answer = client.post("/admin/login", data={"key": ADMIN_KEY}, follow_redirects=False)
    assert answer.status_code == 303


def _policy(answer) -> dict[str, list[str]]:
    directives = [d.split() for d in answer.headers["content-security-policy"].split(";")]
    return {d[0]: d[1:] for d in directives if d}


def assert_protected(answer) -> None:
    policy = _policy(answer)
    assert answer.headers["x-frame-options"] == "DENY", answer.request.url
    assert policy["frame-ancestors"] == ["'none'"]
    assert policy["script-src"] == ["'self'"] and policy["object-src"] == ["'none'"]
    assert answer.headers["x-content-type-options"] == "nosniff"


class _Loads(HTMLParser):
    """What a page makes the browser load or run, as far as its HTML says."""

    def __init__(self):
        super().__init__()
        self.urls: list[str] = []
        self.problems: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.problems += [f"<{tag} {name}=...>: inline handler" for name in attrs
                          if name.startswith("on")]
        if tag == "style":
            self.problems.append("<style> element")
        if tag == "script":
            if "src" in attrs:
                self.urls.append(attrs["src"])
            elif attrs.get("type") != "application/json":  # a data block is never run
                self.problems.append("inline <script>")
        if tag == "link" and attrs.get("rel") == "stylesheet":
            self.urls.append(attrs["href"])
        if tag == "img" and "src" in attrs:
            self.urls.append(attrs["src"])


def test_every_dashboard_response_carries_the_headers(client, stack):
    done = add_journey(stack.settings, "done")
    # Signed out: the sign-in page, the redirect to it, a refused sign-in, a static file.
    for answer in (client.get("/admin/login"),
                   client.get("/admin/journeys", follow_redirects=False),
                   client.post("/admin/login", data={"key": "wrong"}),
                   client.get("/admin/static/app/admin.css")):
        assert answer.status_code in (200, 303, 403)
        assert_protected(answer)
    _signed_in(client)
    pages = ["/admin", "/admin/journeys", f"/admin/journeys/{done}", "/admin/map",
             "/admin/cameras", "/admin/keys", "/admin/journeys/progress.json?ids=x",
             "/admin/api/signs?bbox=0,0,1,1", "/admin/static/leaflet/leaflet.js"]
    for path in pages:
        answer = client.get(path, follow_redirects=False)
        assert answer.status_code in (200, 303), path
        assert_protected(answer)
    # Errors: a route's 404 and 400, the router's 404, a refused post.
    errors = [client.get("/admin/journeys/nope"), client.get("/admin/no-such-page"),
              client.get("/admin/api/signs?bbox=x"),
              client.post(f"/admin/journeys/{done}/retry", follow_redirects=False)]
    assert [a.status_code for a in errors] == [404, 404, 400, 409]
    for answer in errors:
        assert_protected(answer)
    # The API's own answers are not the dashboard's: no page policy on them.
    assert "content-security-policy" not in client.get("/api/v1/health").headers


def test_pages_load_nothing_the_policy_refuses(client, stack):
    """Every script, sheet and image a page names is on the dashboard's origin (and loads), and no
    page runs inline script; the base map's tiles are admitted as images."""
    done = add_journey(stack.settings, "done")
    failed = add_journey(stack.settings, "failed")
    page = client.get("/admin/login")
    seen = {"/admin/login": page.text}
    _signed_in(client)
    for path in ("/admin/journeys", f"/admin/journeys/{done}", "/admin/map", "/admin/cameras",
                 "/admin/keys"):
        seen[path] = client.get(path).text
    assert f'data-id="{failed}"' in seen["/admin/journeys"]  # a delete form with its question
    for path, html in seen.items():
        loads = _Loads()
        loads.feed(html)
        assert loads.problems == [], path
        for url in loads.urls:
            assert url.startswith("/admin/"), (path, url)  # 'self'
            assert client.get(url).status_code == 200, (path, url)
    policy = _policy(page)
    assert policy["img-src"] == ["'self'", "data:", "https://*.tiles.example.org"]
    assert policy["connect-src"] == ["'self'"] and policy["style-src"] == ["'self'"]


@pytest.mark.parametrize(("url", "source"), [
    ("https://tile.openstreetmap.org/{z}/{x}/{y}.png", "https://tile.openstreetmap.org"),
    ("https://{s}.tile.example.org/{z}/{x}/{y}.png", "https://*.tile.example.org"),
    ("http://127.0.0.1:9/{z}/{x}/{y}.png", "http://127.0.0.1:9"),
    ("https://user:secret@tiles.example.org/{z}/{x}/{y}.png", "https://tiles.example.org"),
    ("https://tiles-{s}.example.org/{z}/{x}/{y}.png", "https:"),
    ("/tiles/{z}/{x}/{y}.png", ""),
])
def test_the_tile_servers_source(url, source):
    assert tile_source(url) == source
    assert ("img-src 'self' data:" + (f" {source}" if source else "") + ";"
            in content_security_policy(url))


def _retry(client, stack, headers: dict) -> tuple[int, str]:
    journey_id = add_journey(stack.settings, "failed")
    answer = client.post(f"/admin/journeys/{journey_id}/retry", headers=headers,
                         follow_redirects=False)
    with session_scope(stack.url) as session:
        return answer.status_code, session.get(JourneyRow, journey_id).status


def test_a_post_without_origin_is_judged_by_its_referer(client, stack):
    _signed_in(client)
    foreign = _retry(client, stack, {"Referer": "https://evil.example/admin/journeys"})
    assert foreign == (403, "failed")
    answer = client.post("/admin/logout", headers={"Referer": "https://evil.example/"},
                         follow_redirects=False)
    assert answer.status_code == 403
    assert "post it from the dashboard's own page" in answer.json()["detail"]
    assert _retry(client, stack, {"Referer": "http://testserver/admin/journeys"}) == (
        303, "queued")
    # Origin first: a same-site Referer does not excuse a foreign or a null Origin.
    for origin in ("https://evil.example", "null"):
        assert _retry(client, stack, {"Origin": origin,
                                      "Referer": "http://testserver/admin/journeys"})[0] == 403
    # Neither header: a script or tool, not a browser (which sends Origin on every POST), so
    # not a forgery; let through (app/service/admin/routes.py, _same_origin).
    assert _retry(client, stack, {}) == (303, "queued")


def test_signing_out_deletes_the_cookie_with_samesite_strict(client):
    _signed_in(client)
    answer = client.post("/admin/logout", follow_redirects=False)
    assert answer.status_code == 303
    deletion = answer.headers["set-cookie"].lower()
    assert "max-age=0" in deletion or "expires=thu, 01 jan 1970" in deletion
    for attribute in ("samesite=strict", "httponly", "path=/admin"):
        assert attribute in deletion, deletion
    assert_protected(answer)
