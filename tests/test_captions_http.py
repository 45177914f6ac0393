"""The http captioner against a real HTTP server on 127.0.0.1 that speaks both the OpenAI chat-completions
and the Gemini generateContent APIs, with one scripted behaviour per object category."""

from __future__ import annotations

import dataclasses
import json
import logging
import re
import threading
import time
from datetime import datetime, timedelta, timezone
from email.utils import format_datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image
from sqlalchemy import select

from mixcount.captions.captioning import caption_catalog
from mixcount.captions.http import (
    HttpCaptioner,
    endpoint_url,
    gemini_retry_delay,
    parse_retry_after,
    quota_exhausted,
)
from mixcount.catalog.models import CaptionFailure, CaptionSet, CatalogObject, Render
from mixcount.config import load_config

pytestmark = pytest.mark.network

API_KEY = "sk-test-SECRET-9f8e7d6c5b4a"
KEY_ENV = "MIXCOUNT_TEST_CAPTION_KEY"
TIMEOUT_S = 0.5


def http_conf(**changes: Any):
    """The ``[captions]`` section of default.toml with the test's endpoint, model and limits."""
    return dataclasses.replace(load_config().captions, **changes)


def _good(category: str) -> dict[str, str]:
    return {
        "short": f"{category} test object",
        "concise": f"Bright {category} test object with a smooth surface",
        "detailed": f"A bright {category} test object with a smooth surface. Its seams are dark.",
    }


class Behaviour:
    """What the server answers for the n-th request (0-based) about one category."""

    @staticmethod
    def plan(category: str, n: int, provider: str) -> tuple[int, dict[str, str], Any, float]:
        """(status, headers, body | answer dict | raw str, delay_s)."""
        if category == "ok":
            return 200, {}, _good(category), 0.0
        if category == "ratelimit":
            return (429, {"Retry-After": "2"}, {"error": {"message": "rate limited"}}, 0.0) if n == 0 else (
                200, {}, _good(category), 0.0)
        if category == "ratelimitms":
            return (503, {"retry-after-ms": "1500"}, {"error": {"message": "busy"}}, 0.0) if n == 0 else (
                200, {}, _good(category), 0.0)
        if category == "toolong":  # asks for longer than max_retry_after_s: fail now, do not sleep an hour
            return 429, {"Retry-After": "3600"}, {"error": {"message": "come back later"}}, 0.0
        if category == "flaky":
            return (500, {}, {"error": {"message": "internal"}}, 0.0) if n == 0 else (200, {}, _good(category), 0.0)
        if category == "down":
            return 502, {}, {"error": {"message": "bad gateway"}}, 0.0
        if category == "slow":
            return (200, {}, _good(category), TIMEOUT_S * 4) if n == 0 else (200, {}, _good(category), 0.0)
        if category == "malformed":
            return 200, {}, "this is {not json", 0.0
        if category == "schema":
            return (200, {}, {"short": "only short"}, 0.0) if n == 0 else (200, {}, _good(category), 0.0)
        if category == "unauthorized":
            return 401, {}, "ECHO_KEY", 0.0
        if category == "retryinfo":
            body = {"error": {"code": 429, "status": "RESOURCE_EXHAUSTED", "message": "slow down", "details": [
                {"@type": "type.googleapis.com/google.rpc.RetryInfo", "retryDelay": "3s"}]}}
            return (429, {}, body, 0.0) if n == 0 else (200, {}, _good(category), 0.0)
        if category == "quota":
            if provider == "openai":
                body = {"error": {"message": "You exceeded your current quota", "type": "insufficient_quota",
                                  "code": "insufficient_quota"}}
            else:
                body = {"error": {"code": 429, "status": "RESOURCE_EXHAUSTED", "message": "quota", "details": [
                    {"@type": "type.googleapis.com/google.rpc.QuotaFailure",
                     "violations": [{"quotaId": "GenerateRequestsPerDayPerProjectPerModel-FreeTier"}]},
                    {"@type": "type.googleapis.com/google.rpc.RetryInfo", "retryDelay": "40s"}]}}
            return 429, {}, body, 0.0
        raise AssertionError(f"no behaviour for {category!r}")


class FakeLLM:
    """A ThreadingHTTPServer on 127.0.0.1 speaking both APIs; records every request."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.counts: dict[tuple[str, str], int] = {}
        self.requests: list[dict[str, Any]] = []
        owner = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:  # keep pytest output clean
                pass

            def do_POST(self) -> None:  # noqa: N802
                length = int(self.headers.get("content-length", 0))
                body = json.loads(self.rfile.read(length))
                owner.handle(self, body)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()
        self.base = f"http://127.0.0.1:{self.server.server_address[1]}"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()

    def attempts(self, provider: str, category: str) -> int:
        return self.counts.get((provider, category), 0)

    def handle(self, h: BaseHTTPRequestHandler, body: dict[str, Any]) -> None:
        if h.path == "/v1/chat/completions":
            provider = "openai"
            key = (h.headers.get("authorization") or "").removeprefix("Bearer ")
            texts = [p["text"] for m in body["messages"] if m["role"] == "user" and isinstance(m["content"], list)
                     for p in m["content"] if p.get("type") == "text"]
        elif re.fullmatch(r"/v1beta/models/[\w.-]+:generateContent", h.path):
            provider = "gemini"
            key = h.headers.get("x-goog-api-key") or ""
            texts = [p["text"] for p in body["contents"][0]["parts"] if "text" in p]
        else:
            return self._send(h, 404, {}, {"error": {"message": f"no route {h.path}"}})
        category = json.loads(re.search(r"\{.*\}", texts[0]).group(0))["category"]
        with self.lock:
            n = self.counts.get((provider, category), 0)
            self.counts[(provider, category)] = n + 1
            self.requests.append({"provider": provider, "category": category, "body": body, "path": h.path})
        if key != API_KEY:
            return self._send(h, 401, {}, {"error": {"message": "bad key"}})
        status, headers, payload, delay = Behaviour.plan(category, n, provider)
        if delay:
            time.sleep(delay)
        if payload == "ECHO_KEY":  # a careless server echoing the credential back in its error
            payload = {"error": {"message": f"Incorrect API key provided: {key}", "code": "invalid_api_key"}}
        if status == 200:
            content = payload if isinstance(payload, str) else json.dumps(payload)
            if provider == "openai":
                payload = {"id": "x", "object": "chat.completion",
                           "choices": [{"index": 0, "finish_reason": "stop",
                                        "message": {"role": "assistant", "content": content}}]}
            else:
                payload = {"candidates": [{"content": {"role": "model", "parts": [{"text": content}]},
                                           "finishReason": "STOP"}]}
        self._send(h, status, headers, payload)

    @staticmethod
    def _send(h: BaseHTTPRequestHandler, status: int, headers: dict[str, str], payload: Any) -> None:
        data = json.dumps(payload).encode()
        try:
            h.send_response(status)
            h.send_header("content-type", "application/json")
            h.send_header("content-length", str(len(data)))
            for k, v in headers.items():
                h.send_header(k, v)
            h.end_headers()
            h.wfile.write(data)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the client gave up (timeout test)


@pytest.fixture
def server():
    srv = FakeLLM()
    yield srv
    srv.close()


def _add_objects(catalog, tmp_path: Path, categories: list[str]) -> dict[str, int]:
    ids: dict[str, int] = {}
    with catalog.session() as s:
        for i, cat in enumerate(categories):
            png = tmp_path / f"render_{cat}.png"
            img = Image.new("RGBA", (48, 48), (0, 0, 0, 0))
            img.paste((40 + 20 * i, 90, 200, 255), (12, 12, 36, 36))
            img.save(png)
            obj = CatalogObject(source="folder", source_id=f"{cat}/{i}", name=f"{cat.title()}_{i:04d}",
                                category=cat, model_path=str(tmp_path / "missing.glb"),
                                dim_x=0.05, dim_y=0.04, dim_z=0.03, watertight=True, volume=3e-5)
            s.add(obj)
            s.flush()
            s.add(Render(object_id=obj.id, view="canonical", path=str(png), width=48, height=48))
            ids[cat] = obj.id
        s.commit()
    return ids


CATEGORIES = ["ok", "ratelimit", "ratelimitms", "flaky", "slow", "malformed", "schema", "unauthorized",
              "retryinfo", "quota", "down", "toolong"]
# expected (requests made, success) per category; max_retries = 2 -> at most 3 requests per send
EXPECTED = {
    "ok": (1, True), "ratelimit": (2, True), "ratelimitms": (2, True), "flaky": (2, True), "slow": (2, True),
    "malformed": (2, False), "schema": (2, True), "unauthorized": (1, False), "retryinfo": (2, True),
    "quota": (1, False), "down": (3, False), "toolong": (1, False),
}


@pytest.mark.parametrize("provider", ["openai", "gemini"])
def test_http_captioner_against_loopback_server(provider, server, catalog, tmp_path, monkeypatch, caplog):
    caplog.set_level(logging.DEBUG)
    monkeypatch.setenv(KEY_ENV, API_KEY)
    ids = _add_objects(catalog, tmp_path, CATEGORIES)
    sleeps: list[float] = []
    conf = http_conf(provider=provider, endpoint=server.base, model="vision-test-1", api_key_env=KEY_ENV,
                               timeout_s=TIMEOUT_S, concurrency=3, max_retries=2, backoff_base_s=0.25,
                               backoff_cap_s=1.0, max_retry_after_s=30.0)
    with httpx.Client() as client:
        cap = HttpCaptioner(conf, client, sleep=sleeps.append, rng=np.random.default_rng(0))
        summary = caption_catalog(catalog, cap, concurrency=conf.concurrency, colour_source="model")

    for cat, (attempts, _ok) in EXPECTED.items():
        assert server.attempts(provider, cat) == attempts, (cat, server.attempts(provider, cat))
    assert summary.captioned == sum(ok for _, ok in EXPECTED.values())
    assert summary.failed == sum(not ok for _, ok in EXPECTED.values())
    # server-given waits were honoured: Retry-After 2 s, retry-after-ms 1500, RetryInfo 3 s, and plain
    # backoff for 500 / 502 stays within [base/2, cap]
    assert any(abs(s - 2.0) < 1e-9 for s in sleeps)
    assert any(abs(s - 1.5) < 1e-9 for s in sleeps)
    assert any(abs(s - 3.0) < 1e-9 for s in sleeps)
    assert all(0.125 <= s <= 3.0 for s in sleeps)

    with catalog.session() as s:
        sets = {cs.object_id: cs for cs in s.scalars(select(CaptionSet))}
        failures = {f.object_id: f for f in s.scalars(select(CaptionFailure))}
    for cat, (attempts, ok) in EXPECTED.items():
        oid = ids[cat]
        if ok:
            cs = sets[oid]
            assert (cs.short, cs.concise, cs.detailed) == tuple(_good(cat).values())
            assert (cs.captioner, cs.provider, cs.model, cs.active) == ("http", provider, "vision-test-1", True)
            assert len(cs.response_hash) == 64
            assert oid not in failures
        else:
            assert oid not in sets
            assert failures[oid].attempts == attempts
    assert "HTTP 401" in failures[ids["unauthorized"]].error
    assert "quota" in failures[ids["quota"]].error
    assert "after repair" in failures[ids["malformed"]].error
    assert "asks to wait 3600" in failures[ids["toolong"]].error

    # requests carried the image and the schema in the provider's own format
    first = next(r["body"] for r in server.requests if r["provider"] == provider and r["category"] == "ok")
    if provider == "openai":
        parts = first["messages"][1]["content"]
        assert parts[1]["image_url"]["url"].startswith("data:image/png;base64,")
        assert first["response_format"]["type"] == "json_schema"
        assert first["response_format"]["json_schema"]["schema"]["required"] == ["short", "concise", "detailed"]
    else:
        assert first["contents"][0]["parts"][1]["inline_data"]["mime_type"] == "image/png"
        assert first["generationConfig"]["responseMimeType"] == "application/json"
        assert first["generationConfig"]["responseSchema"]["type"] == "OBJECT"
    repair = [r["body"] for r in server.requests if r["category"] == "schema"][1]
    assert "previous answer was invalid" in json.dumps(repair)

    # the key is in no byte of the database files nor of the captured logs
    catalog.engine.dispose()
    db_files = list(tmp_path.glob("catalog.db*"))
    assert any(p.name == "catalog.db" for p in db_files)
    for path in db_files:
        assert API_KEY.encode() not in path.read_bytes(), path
    assert caplog.records, "expected the captioner to log retries"
    assert API_KEY not in caplog.text
    assert all(API_KEY not in str(r.args) for r in caplog.records)


def test_resume_skips_same_captioner_and_force_recaptions(server, catalog, tmp_path, monkeypatch):
    monkeypatch.setenv(KEY_ENV, API_KEY)
    _add_objects(catalog, tmp_path, ["ok"])
    conf = http_conf(provider="openai", endpoint=server.base + "/v1", model="m", api_key_env=KEY_ENV,
                               timeout_s=2.0, concurrency=1, max_retries=0)
    with httpx.Client() as client:
        cap = HttpCaptioner(conf, client, sleep=lambda s: None)
        assert caption_catalog(catalog, cap, concurrency=conf.concurrency, colour_source="model").captioned == 1
        again = caption_catalog(catalog, cap, concurrency=conf.concurrency, colour_source="model")
        assert (again.captioned, again.skipped) == (0, 1)
        forced = caption_catalog(catalog, cap, concurrency=1, colour_source="model", force=True)
        assert forced.captioned == 1
    assert server.attempts("openai", "ok") == 2
    with catalog.session() as s:
        sets = s.scalars(select(CaptionSet)).all()
    assert len(sets) == 2 and sum(cs.active for cs in sets) == 1


def test_missing_key_env_is_a_config_error(monkeypatch):
    from mixcount.errors import ConfigError

    monkeypatch.delenv(KEY_ENV, raising=False)
    with pytest.raises(ConfigError, match=KEY_ENV):
        HttpCaptioner(http_conf(model="m", api_key_env=KEY_ENV))


def test_retry_hint_parsing():
    assert parse_retry_after({"retry-after": "7"}) == 7.0
    assert parse_retry_after({"retry-after-ms": "250", "retry-after": "9"}) == 0.25
    now = datetime(2026, 1, 1, tzinfo=timezone.utc)
    date = format_datetime(now + timedelta(seconds=30), usegmt=True)
    assert parse_retry_after({"retry-after": date}, now=now) == pytest.approx(30.0)
    assert parse_retry_after({}) is None
    body = {"error": {"details": [{"@type": "type.googleapis.com/google.rpc.RetryInfo", "retryDelay": "1.5s"}]}}
    assert gemini_retry_delay(body) == 1.5
    assert quota_exhausted("openai", {"error": {"code": "insufficient_quota"}})
    assert not quota_exhausted("openai", {"error": {"code": "rate_limit_exceeded"}})
    assert not quota_exhausted("gemini", body)


def test_urls_for_both_providers():
    assert endpoint_url(http_conf(provider="openai", model="m", endpoint="http://h:1")) == "http://h:1/v1/chat/completions"
    assert endpoint_url(http_conf(provider="openai", model="m", endpoint="http://h/v1/")) == "http://h/v1/chat/completions"
    assert endpoint_url(http_conf(provider="gemini", model="g-1", endpoint="")) == (
        "https://generativelanguage.googleapis.com/v1beta/models/g-1:generateContent")


def test_cli_http_captioner_uses_config_and_env_key(server, catalog, db_url, tmp_path, monkeypatch, capsys):
    from mixcount.cli import main

    monkeypatch.setenv(KEY_ENV, API_KEY)
    ids = _add_objects(catalog, tmp_path, ["ok", "unauthorized"])
    db = db_url.removeprefix("sqlite:///")
    args = ["--db", db, "--set", f"captions.endpoint={server.base}", "--set", "captions.model=models/g-1",
            "--set", "captions.provider=gemini", "--set", f"captions.api_key_env={KEY_ENV}",
            "--set", "captions.max_retries=0", "catalog", "caption", "--captioner", "http", "--json"]
    assert main(args) == 3  # one of the two failed (HTTP 401): finished, items failed (docs/faults.md, "Exit codes")
    captured = capsys.readouterr()
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert (summary["captioned"], summary["failed"], summary["provider"]) == (1, 1, "gemini")
    assert summary["failures"][0]["object_id"] == ids["unauthorized"]
    assert API_KEY not in captured.out + captured.err
    assert server.attempts("gemini", "ok") == 1

    monkeypatch.delenv(KEY_ENV)
    assert main(args) == 2  # no key in the environment: a clear configuration error, nothing sent
    assert KEY_ENV in capsys.readouterr().err
    assert server.attempts("gemini", "ok") == 1
