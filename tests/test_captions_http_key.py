"""The captioner's key stays secret (issue 60): a real loopback server echoes it back in every form a
careless server might (lower / upper case, URL-encoded, JSON \\u-escaped, HTML entities, base64 at each
alignment, a Basic header, hex, a part of it, inside a caption it answers with) and none of those forms
reaches stderr, the log records or a byte of the database. An ``http://`` endpoint off this machine is
refused unless the config allows it."""

from __future__ import annotations

import base64
import html
import json
import logging
import re
import urllib.parse
from pathlib import Path

import httpx
import numpy as np
import pytest
from sqlalchemy import select
from test_captions_http import API_KEY, KEY_ENV, FakeLLM, _add_objects, _good, http_conf

from mixcount.captions.http import HttpCaptioner, is_loopback_host
from mixcount.captions.redact import Redactor
from mixcount.catalog.models import CaptionFailure, CaptionSet
from mixcount.errors import ConfigError

pytestmark = pytest.mark.network


def _forms(key: str) -> dict[str, str]:
    """Every form of ``key`` the server echoes, by category name (letters only: categories are words)."""
    raw = key.encode()
    return {
        "asis": key,
        "lower": key.lower(),
        "upper": key.upper(),
        "urlenc": urllib.parse.quote(key, safe=""),
        "urlall": "".join(f"%{b:02x}" for b in raw),
        "jsonu": "".join(f"\\u{ord(c):04x}" for c in key),
        "entities": "".join(f"&#{ord(c)};" for c in key),
        "basesf": base64.b64encode(raw).decode(),
        "basic": "Basic " + base64.b64encode(b"user:" + raw).decode(),
        "urlsafe": base64.urlsafe_b64encode(b"xy" + raw).decode(),
        "hexed": raw.hex().upper(),
        "tail": key[-12:].lower(),
        "head": key[:10],
    }


FORMS = _forms(API_KEY)


def _unescaped(text: str) -> str:
    """``text`` with JSON \\u escapes (also escaped again), URL encoding and HTML entities undone."""
    for _ in range(3):
        text = re.sub(r"\\+u([0-9a-fA-F]{4})", lambda m: chr(int(m.group(1), 16)), text)
        text = html.unescape(urllib.parse.unquote(text))
    return text


def _leaks(text: str) -> list[str]:
    """The forms of the key found in ``text``, checked without the redactor: each form's middle part
    (what stays of it whatever surrounds it) and the key's own 8-character runs, case-folded, in the
    text as it is and with its escapes undone."""
    text = text + "\n" + _unescaped(text)
    low = text.lower()
    found = [name for name, form in FORMS.items() if name != "basic" and form[2:-2].lower() in low]
    key = API_KEY.lower()
    found += [f"run {key[i:i + 8]!r}" for i in range(len(key) - 7) if key[i:i + 8] in low]
    found += ["basic"] if base64.b64encode(b"user:" + API_KEY.encode()).decode()[8:-4] in text else []
    return found


class EchoLLM(FakeLLM):
    """The loopback server of test_captions_http, answering per category: 401 with the key in the form
    the category names, or (category ``echoanswer``) a 200 whose captions hold the key in lower case."""

    def handle(self, h, body):  # noqa: ANN001
        texts = [p["text"] for m in body["messages"] if m["role"] == "user" and isinstance(m["content"], list)
                 for p in m["content"] if p.get("type") == "text"]
        category = json.loads(texts[0][texts[0].index("{"):])["category"]
        with self.lock:
            self.counts[("openai", category)] = self.counts.get(("openai", category), 0) + 1
        key = (h.headers.get("authorization") or "").removeprefix("Bearer ")
        if category == "echoanswer":
            answer = dict(_good("mug"), detailed=f"A mug. Your key {key.lower()} works fine.")
            payload = {"choices": [{"index": 0, "message": {"role": "assistant", "content": json.dumps(answer)}}]}
            return self._send(h, 200, {}, payload)
        echo = _forms(key)[category]
        return self._send(h, 401, {"www-authenticate": f"Bearer realm={echo}"},
                          {"error": {"message": f"Incorrect API key provided: {echo}", "code": "invalid_api_key"}})


@pytest.fixture
def echo_server():
    srv = EchoLLM()
    yield srv
    srv.close()


def test_no_form_of_the_key_reaches_stderr_logs_or_database(echo_server, catalog, db_url, tmp_path, monkeypatch,
                                                           capsys, caplog) -> None:
    from mixcount.cli import main

    caplog.set_level(logging.DEBUG)
    monkeypatch.setenv(KEY_ENV, API_KEY)
    categories = [*FORMS, "echoanswer"]
    ids = _add_objects(catalog, tmp_path, categories)
    db = db_url.removeprefix("sqlite:///")
    rc = main(["--db", db, "--set", f"captions.endpoint={echo_server.base}", "--set", "captions.model=m",
               "--set", f"captions.api_key_env={KEY_ENV}", "--set", "captions.max_retries=0",
               "catalog", "caption", "--captioner", "http", "--json"])
    captured = capsys.readouterr()
    assert rc == 3, captured.err  # objects failed (the key forms are refused): exit 3, one line each
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert (summary["captioned"], summary["failed"]) == (1, len(FORMS))
    assert all(echo_server.attempts("openai", c) == 1 for c in categories)
    assert _leaks(captured.out + captured.err) == []
    assert _leaks(caplog.text) == []
    catalog.engine.dispose()
    with catalog.session() as s:
        failures = {f.object_id: f.error for f in s.scalars(select(CaptionFailure))}
        detailed = s.scalars(select(CaptionSet.detailed).where(CaptionSet.object_id == ids["echoanswer"])).one()
    for name in FORMS:
        assert "HTTP 401" in failures[ids[name]] and "[redacted]" in failures[ids[name]], (name, failures[ids[name]])
    assert detailed == "A mug. Your key [redacted] works fine."
    catalog.engine.dispose()
    for path in tmp_path.glob("catalog.db*"):
        assert _leaks(path.read_bytes().decode("latin-1")) == [], path


def test_redactor_leaves_other_text_alone() -> None:
    redact = Redactor(API_KEY)
    text = "Bright red ceramic mug with a white handle; sk- and test words; 9f8e7 is a colour code."
    assert redact(text) == text
    assert redact("Authorization: Bearer abc.def-123") == "Authorization: Bearer [redacted]"
    short = Redactor("abc")  # a key shorter than a run is redacted whole, in any case
    assert short("x ABC y") == "x [redacted] y"


@pytest.mark.parametrize("endpoint, allowed", [
    ("http://192.0.2.7:8080", False), ("http://llm.example.com/v1", False), ("http://0.0.0.0:9000", False),
    ("http://127.0.0.1:8080", True), ("http://127.1.2.3", True), ("http://localhost:11434", True),
    ("http://[::1]:8000", True), ("http://gpu.localhost", True), ("https://llm.example.com", True),
])
def test_plain_http_off_this_machine_is_refused(endpoint: str, allowed: bool, monkeypatch) -> None:
    monkeypatch.setenv(KEY_ENV, API_KEY)
    conf = http_conf(model="m", api_key_env=KEY_ENV, endpoint=endpoint)
    if allowed:
        HttpCaptioner(conf, httpx.Client()).close()
    else:
        with pytest.raises(ConfigError, match="plain http:// to another machine.*allow_plain_http"):
            HttpCaptioner(conf, httpx.Client())
        HttpCaptioner(http_conf(model="m", api_key_env=KEY_ENV, endpoint=endpoint, allow_plain_http=True),
                      httpx.Client()).close()


def test_cli_refuses_plain_http_in_one_line(catalog, db_url, tmp_path: Path, monkeypatch, capsys) -> None:
    from mixcount.cli import main

    monkeypatch.setenv(KEY_ENV, API_KEY)
    _add_objects(catalog, tmp_path, ["ok"])
    rc = main(["--db", db_url.removeprefix("sqlite:///"), "--set", "captions.endpoint=http://192.0.2.7:8080",
               "--set", "captions.model=m", "--set", f"captions.api_key_env={KEY_ENV}",
               "catalog", "caption", "--captioner", "http"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        "error: captions endpoint http://192.0.2.7:8080 is plain http:// to another machine: the API key would "
        "cross the network in clear text; use https://, or set captions.allow_plain_http = true if that network "
        "is yours"]


def test_loopback_names() -> None:
    assert is_loopback_host("LOCALHOST.") and is_loopback_host("::1") and is_loopback_host("127.255.0.1")
    assert not is_loopback_host("localhost.example.com") and not is_loopback_host("10.0.0.1")
    assert np.all([not is_loopback_host(h) for h in ("", "example", "128.0.0.1")])
