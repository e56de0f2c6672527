"""The OpenAPI document and its pages over the real server: ``/docs`` and ``/redoc``
load only what this server serves (no CDN), and every operation of ``/openapi.json``
has a summary, a description and typed responses."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from urllib.parse import urljoin, urlsplit

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

#: Attributes through which a page makes the browser fetch something.
URL_ATTRS = {"src", "href", "spec-url", "data", "poster", "action", "srcset"}
LOOPBACK = {"127.0.0.1", "localhost", "::1"}


class _Refs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.urls: list[str] = []
        self.scripts: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        self._in_script = tag == "script"
        for name, value in attrs:
            if name in URL_ATTRS and value:
                self.urls.append(value)

    def handle_endtag(self, tag):
        self._in_script = False

    def handle_data(self, data):
        if self._in_script and data.strip():
            self.scripts.append(data)


def _page_refs(html: str) -> list[str]:
    """Every URL the page's markup and inline scripts name."""
    p = _Refs()
    p.feed(html)
    urls = list(p.urls)
    for script in p.scripts:
        # string literals that are paths or URLs (SwaggerUIBundle({url: '/openapi.json'}),
        # window.location.origin + '/docs/oauth2-redirect')
        urls += re.findall(r"""["'](/[^"'\s]*|[a-z]+://[^"'\s]+)["']""", script)
    return urls


def _assert_local_and_served(c, base: str, page: str) -> list[str]:
    html = c.get(page).text
    assert not re.search(r"(?<![\w.])//(?!127\.0\.0\.1|localhost)[\w-]+\.", html), \
        "a protocol-relative URL to another host"
    for m in re.finditer(r"[a-z]+://([^/\s\"'<>:]+)", html):
        assert m.group(1) in LOOPBACK, f"{page} refers to {m.group(0)}"
    refs = _page_refs(html)
    assert refs, f"{page} names no asset"
    for ref in refs:
        url = urljoin(base + page, ref)
        assert urlsplit(url).hostname in LOOPBACK, f"{page}: {ref} is not on this server"
        r = c.get(url)
        assert r.status_code == 200, f"{page}: {ref} -> {r.status_code}"
        assert r.content, f"{page}: {ref} is empty"
    return refs


def test_docs_and_redoc_load_only_local_assets(stack):
    h, api = stack
    c = api.client
    base = f"http://127.0.0.1:{api.port}"
    swagger = _assert_local_and_served(c, base, "/docs")
    assert any(r.endswith("swagger-ui-bundle.js") for r in swagger)
    assert any(r.endswith(".css") for r in swagger)
    assert "/openapi.json" in swagger
    redoc = _assert_local_and_served(c, base, "/redoc")
    assert any(r.endswith("redoc.standalone.js") for r in redoc)
    # the style sheet's own references (fonts, images) are inline or local too
    css_ref = next(r for r in swagger if r.endswith(".css"))
    css = c.get(urljoin(base, css_ref)).text
    for ref in re.findall(r"url\(\s*['\"]?([^'\")]+)", css):
        assert ref.startswith("data:") or urlsplit(urljoin(base, ref)).hostname in LOOPBACK, ref
        assert "@import" not in css


def test_the_pages_may_load_nothing_from_another_host(stack):
    """ReDoc's bundle shows the Redocly logo from its CDN whatever the page says: the
    pages' Content-Security-Policy keeps the browser on this server."""
    h, api = stack
    c = api.client
    for page in ("/docs", "/redoc"):
        policy = c.get(page).headers.get("content-security-policy", "")
        directives = {d.split()[0]: d.split()[1:] for d in policy.split(";") if d.strip()}
        assert directives.get("default-src") == ["'none'"], policy
        for name, sources in directives.items():
            if name.endswith("-src"):
                assert set(sources) <= {"'self'", "'none'", "'unsafe-inline'", "data:",
                                        "blob:"}, (page, name, sources)
        assert directives.get("connect-src") == ["'self'"]
        assert directives.get("img-src") and "https:" not in policy and "*" not in policy
    assert "content-security-policy" not in c.get("/health").headers


def _resolve(doc, schema):
    while "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[1]
        schema = doc["components"]["schemas"][name]
    return schema


_TYPED = ("type", "$ref", "anyOf", "oneOf", "allOf", "enum", "const")


def _untyped(doc, schema, where, seen) -> list[str]:
    """Places in ``schema`` (and what it refers to) that say nothing of their type."""
    if "$ref" in schema:
        if schema["$ref"] in seen:
            return []
        seen.add(schema["$ref"])
        return _untyped(doc, _resolve(doc, schema), schema["$ref"], seen)
    if not any(k in schema for k in _TYPED):
        return [where]
    out = []
    for k in ("anyOf", "oneOf", "allOf"):
        for i, sub in enumerate(schema.get(k, [])):
            out += _untyped(doc, sub, f"{where}/{k}{i}", seen)
    if schema.get("type") == "array":
        out += _untyped(doc, schema.get("items", {}), f"{where}[]", seen)
    for name, sub in schema.get("properties", {}).items():
        out += _untyped(doc, sub, f"{where}.{name}", seen)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        out += _untyped(doc, extra, f"{where}{{}}", seen)
    return out


def test_openapi_every_operation_has_a_summary_and_typed_responses(stack):
    h, api = stack
    doc = api.client.get("/openapi.json").json()
    ops = [(p, m, op) for p, item in doc["paths"].items() for m, op in item.items()]
    assert {p for p, _, _ in ops} >= {
        "/health", "/api/v1/units", "/api/v1/units/{unit}/status",
        "/api/v1/units/{unit}/grades", "/api/v1/units/{unit}/transitions",
        "/api/v1/units/{unit}/transitions/{tid}", "/api/v1/units/{unit}/disturbances",
        "/api/v1/units/{unit}/events"}
    for path, method, op in ops:
        where = f"{method.upper()} {path}"
        assert op.get("summary", "").strip(), f"{where}: no summary"
        assert len(op.get("description", "")) >= 20, f"{where}: no description"
        for code, resp in op["responses"].items():
            schema = resp.get("content", {}).get("application/json", {}).get("schema")
            assert schema is not None, f"{where} {code}: no JSON schema"
            target = _resolve(doc, schema)
            if target.get("type") == "array":
                target = _resolve(doc, target["items"])
            assert target.get("properties"), f"{where} {code}: not a model"
            assert _untyped(doc, schema, f"{where} {code}", set()) == []
    events = doc["paths"]["/api/v1/units/{unit}/events"]["get"]
    item = _resolve(doc, _resolve(doc, events["responses"]["200"]["content"][
        "application/json"]["schema"])["items"])
    assert set(item["properties"]) == {"id", "time", "process_time_h", "kind", "detail",
                                       "identity"}
    assert {p["name"] for p in events["parameters"]} >= {"unit", "since", "limit"}
