"""The HTTP captioner: a vision LLM behind an OpenAI-compatible or a Gemini endpoint (httpx).

One request per object: the canonical render (PNG data, composited on white, downscaled), the object's
name (as the captions should say it) and category, and a system prompt stating the caption rules go out
(no dimensions, no mesh facts: :meth:`CaptionInput.facts`); a JSON object ``{short, concise, detailed}`` constrained by a JSON schema comes back.

* ``openai``: ``POST {endpoint}/v1/chat/completions``, ``Authorization: Bearer``, image as a
  ``data:image/png;base64,...`` URI in an ``image_url`` part, ``response_format`` = ``json_schema`` (strict).
* ``gemini``: ``POST {endpoint}/v1beta/models/{model}:generateContent``, ``x-goog-api-key`` header (never
  the ``?key=`` query, which would put the key in every logged URL), image as ``inline_data``,
  ``generationConfig.responseMimeType = application/json`` + ``responseSchema``.

Failure policy (every sleep goes through the injected ``sleep`` so tests stay fast):

* every request ends within ``timeout_s``, connect to last byte (:mod:`mixcount.captions.deadline`: a
  server that drips its answer cannot hold it longer);
* 408, 409, 429, 5xx, timeouts and connection errors are retried up to ``max_retries`` times with capped
  exponential backoff and "equal" jitter (half the step fixed, half random), unless the server says how long
  to wait: ``retry-after-ms``, ``Retry-After`` (seconds or HTTP date), or Gemini's
  ``google.rpc.RetryInfo.retryDelay``; a wait longer than ``max_retry_after_s`` fails at once;
* 400, 401, 403, 404 (any other 4xx) and quota-exhausted answers (OpenAI ``insufficient_quota``, Gemini
  ``QuotaFailure`` on a per-day quota) are not retried;
* a 200 whose body or content is not valid JSON, or violates the schema / word bounds, gets one repair
  request (the bad answer and the validation error are sent back), then counts as a failure.

Failures raise :class:`CaptionRequestError` carrying the number of HTTP requests made; the batch records
it and goes on. The API key is read from the environment variable named in config and sent only in a
request header, never over plain ``http://`` to another machine (:func:`check_transport`). Whatever a
server sends back passes through :class:`~mixcount.captions.redact.Redactor` before it is stored, logged
or raised: the key in any case or encoding, or a part of it, becomes ``[redacted]`` (also in the log
records of httpx / httpcore while the captioner is open).
"""

from __future__ import annotations

import base64
import email.utils
import io
import json
import logging
import os
import re
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Mapping

import httpx
import numpy as np

from mixcount.captions.base import LLM_WORD_BOUNDS, TIERS, CaptionInput, CaptionResult, check_tiers
from mixcount.captions.check import blocking, reasons
from mixcount.captions.deadline import deadline_client, request_deadline
from mixcount.captions.redact import RedactingFilter, Redactor
from mixcount.config import CaptionsConfig
from mixcount.errors import CaptionError, CaptionRequestError, ConfigError, UnusableAnswerError

log = logging.getLogger("mixcount.captions.http")

PROVIDERS = ("openai", "gemini")
DEFAULT_ENDPOINTS = {"openai": "https://api.openai.com", "gemini": "https://generativelanguage.googleapis.com"}
RETRY_STATUSES = frozenset({408, 409, 429})

SYSTEM_PROMPT = (
    "You write the prompts a person would type into an object counter to pick out one kind of object among "
    "similar ones. The image shows the object alone on a white background, as it looks in every scene; you "
    "also get the name a person gave it and its category (a shelf label). Answer with JSON holding three "
    "fields. short: 2 to 4 words = colour or pattern plus the noun, as seen (e.g. 'gold paneled "
    "volleyball', 'red coffee mug', 'camo patterned basketball'). concise: 3 to 10 words, the phrase that "
    "picks this object out among similar ones: colour, pattern, material or a visible part (e.g. 'Shiny "
    "golden volleyball with dark seams'). detailed: one or two sentences of appearance: which part has "
    "which colour, print or pattern, material, and shape words a person uses (e.g. 'Shiny golden volleyball "
    "with segmented panels joined by dark seams.'). Rules. The name wins where it knows: keep its colour "
    "words (a 'Black bowl' with a white pattern is a black bowl with a white pattern), its compound noun "
    "('ice-cream dispenser', never 'ice dispenser') and the capitals of proper nouns ('Stanford bunny'). "
    "Name the object with that specific noun, never with the broad category, and never add the category "
    "after the noun. Colours are the ones the image shows. No sizes: no size words (large, small, "
    "hand-sized, mini) and no measurements in units in any field, since every object is rescaled in the "
    "scenes. No facts about the 3D model: no surface, watertightness, part counts, polygon counts or colour "
    "percentages. No ids, numbers, file or source names (high-res, copy, recolour, PartNet). No filler "
    "such as 'with an irregular shape'. Do not repeat a word within the short or the concise text. Do not "
    "mention the background, the photograph or the render."
)

JSON_SCHEMA: dict[str, Any] = {
    "type": "object",
    "properties": {t: {"type": "string"} for t in TIERS},
    "required": list(TIERS),
    "additionalProperties": False,
}
GEMINI_SCHEMA: dict[str, Any] = {
    "type": "OBJECT",
    "properties": {t: {"type": "STRING"} for t in TIERS},
    "required": list(TIERS),
    "propertyOrdering": list(TIERS),
}


def check_http_config(config: CaptionsConfig) -> None:
    """What the http captioner needs beyond what every config satisfies."""
    if config.provider not in PROVIDERS:
        raise ConfigError(f"captions.provider must be one of {PROVIDERS}, got {config.provider!r}")
    if not config.model:
        raise ConfigError("captions.model must name the model for the http captioner")


HTTP_STACK_LOGGERS = ("httpx", "httpcore.connection", "httpcore.http11", "httpcore.http2", "httpcore.proxy",
                      "mixcount.captions.http", "mixcount.captions.captioning")


def is_loopback_host(host: str) -> bool:
    """True for a host name that cannot leave this machine: localhost (and *.localhost, RFC 6761),
    127.0.0.0/8, ::1. Names are not resolved: a name that resolves to 127.0.0.1 today may not tomorrow."""
    import ipaddress

    name = host.strip("[]").rstrip(".").lower()
    if name == "localhost" or name.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def check_transport(config: CaptionsConfig, url: str) -> None:
    """A ConfigError for a plain ``http://`` URL to another machine, unless ``captions.allow_plain_http``:
    the API key (and every image) would cross the network in clear text."""
    parsed = httpx.URL(url)
    if parsed.scheme == "http" and not is_loopback_host(parsed.host) and not config.allow_plain_http:
        raise ConfigError(
            f"captions endpoint {parsed.scheme}://{parsed.host}{':' + str(parsed.port) if parsed.port else ''} is "
            "plain http:// to another machine: the API key would cross the network in clear text; use https://, "
            "or set captions.allow_plain_http = true if that network is yours")


def endpoint_url(config: CaptionsConfig) -> str:
    """The request URL for ``captions.provider`` / ``endpoint`` / ``model``."""
    base = (config.endpoint or DEFAULT_ENDPOINTS[config.provider]).rstrip("/")
    if config.provider == "openai":
        if base.endswith("/chat/completions"):
            return base
        return base + ("/chat/completions" if base.endswith("/v1") else "/v1/chat/completions")
    if base.endswith(":generateContent"):
        return base
    model = config.model.removeprefix("models/")
    if re.search(r"/v1(beta\d*)?$", base):
        return f"{base}/models/{model}:generateContent"
    return f"{base}/v1beta/models/{model}:generateContent"


def encode_image(path: Path, max_px: int) -> str:
    """The render as base64 PNG: transparent pixels composited on white, longest side <= ``max_px``."""
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        rgba = im.convert("RGBA")
    canvas = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
    canvas.alpha_composite(rgba)
    rgb = canvas.convert("RGB")
    if max(rgb.size) > max_px:
        rgb.thumbnail((max_px, max_px), Image.Resampling.LANCZOS)
    buf = io.BytesIO()
    rgb.save(buf, format="PNG", optimize=True)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def parse_retry_after(headers: Mapping[str, str], now: datetime | None = None) -> float | None:
    """Seconds to wait from ``retry-after-ms`` or ``Retry-After`` (delta-seconds or HTTP date)."""
    ms = headers.get("retry-after-ms")
    if ms:
        try:
            return max(0.0, float(ms) / 1000.0)
        except ValueError:
            pass
    value = headers.get("retry-after")
    if not value:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=timezone.utc)
    return max(0.0, (when - (now or datetime.now(timezone.utc))).total_seconds())


def _error_details(body: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    err = body.get("error") if isinstance(body, dict) else None
    if isinstance(err, list) and err and isinstance(err[0], dict):  # some Gemini proxies wrap in a list
        err = err[0].get("error", err[0])
    if not isinstance(err, dict):
        return {}, []
    details = err.get("details") if isinstance(err.get("details"), list) else []
    return err, [d for d in details if isinstance(d, dict)]


def gemini_retry_delay(body: Any) -> float | None:
    """``RetryInfo.retryDelay`` ("12s", "1.5s") from a Gemini error body, in seconds."""
    _, details = _error_details(body)
    for d in details:
        if str(d.get("@type", "")).endswith("google.rpc.RetryInfo"):
            m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)s\s*", str(d.get("retryDelay", "")))
            if m:
                return float(m.group(1))
    return None


def quota_exhausted(provider: str, body: Any) -> bool:
    """True for answers saying the account's quota is spent (retrying soon cannot help)."""
    err, details = _error_details(body)
    if provider == "openai":
        return "insufficient_quota" in (str(err.get("code", "")), str(err.get("type", "")))
    for d in details:
        if str(d.get("@type", "")).endswith("google.rpc.QuotaFailure"):
            for v in d.get("violations") or []:
                if isinstance(v, dict) and "perday" in str(v.get("quotaId", "")).lower():
                    return True
    return False


class HttpCaptioner:
    """Captioner over HTTP. ``client`` is injected (tests pass one; the CLI makes one); thread-safe."""

    name = "http"

    def __init__(
        self,
        config: CaptionsConfig,
        client: httpx.Client | None = None,
        *,
        api_key: str | None = None,
        sleep: Callable[[float], None] = time.sleep,
        rng: np.random.Generator | None = None,
    ) -> None:
        check_http_config(config)
        self.config = config
        self.provider = config.provider
        self.model = config.model
        self.prompt_version = config.http_prompt_version
        self.concurrency = config.concurrency
        if api_key is None:
            if config.api_key_env:
                api_key = os.environ.get(config.api_key_env, "")
                if not api_key:
                    raise ConfigError(
                        f"the http captioner needs an API key in the environment variable {config.api_key_env} "
                        "(captions.api_key_env)"
                    )
            else:
                api_key = ""
        self._key = api_key
        self._redactor = Redactor(api_key)
        self.url = endpoint_url(config)
        check_transport(config, self.url)
        self._log_filter = RedactingFilter(self._redactor)
        for name in HTTP_STACK_LOGGERS:
            logging.getLogger(name).addFilter(self._log_filter)
        self._own_client = client is None
        # captions.timeout_s bounds each connect and read and, through request_deadline, the whole request
        self.client = client or deadline_client(
            timeout=config.timeout_s,
            limits=httpx.Limits(max_connections=max(2, config.concurrency)),
        )
        self._sleep = sleep
        self._rng = rng or np.random.default_rng()
        self._rng_lock = threading.Lock()  # numpy Generators are not thread-safe

    def close(self) -> None:
        if self._own_client:
            self.client.close()
        for name in HTTP_STACK_LOGGERS:
            logging.getLogger(name).removeFilter(self._log_filter)

    # --- text hygiene -------------------------------------------------------------------------------------
    def redact(self, text: str) -> str:
        """Remove the API key in any case or encoding, a part of it, and a Bearer token from any text
        before it is stored, logged or raised (:class:`~mixcount.captions.redact.Redactor`)."""
        return self._redactor(text)

    def _headers(self) -> dict[str, str]:
        headers = {"content-type": "application/json", "accept": "application/json"}
        if self._key:
            if self.provider == "openai":
                headers["authorization"] = f"Bearer {self._key}"
            else:
                headers["x-goog-api-key"] = self._key
        return headers

    # --- request bodies -----------------------------------------------------------------------------------
    def _user_text(self, item: CaptionInput, has_image: bool) -> str:
        facts = json.dumps(item.facts(with_image=has_image), sort_keys=True)
        if has_image:
            return (f"Describe the object in the image. Its name and category (keep the name's colour words, "
                    f"noun and proper nouns; the image gives every other colour): {facts}")
        return ("No image is available; describe the object from its name, its category and the colours seen "
                f"on its material: {facts}")

    def build_body(self, item: CaptionInput) -> dict[str, Any]:
        image = encode_image(item.render_path, self.config.max_image_px) if item.render_path else None
        text = self._user_text(item, image is not None)
        if self.provider == "openai":
            content: list[dict[str, Any]] = [{"type": "text", "text": text}]
            if image:
                content.append({"type": "image_url", "image_url": {"url": f"data:image/png;base64,{image}"}})
            return {
                "model": self.model,
                "temperature": self.config.temperature,
                "messages": [{"role": "system", "content": SYSTEM_PROMPT}, {"role": "user", "content": content}],
                "response_format": {
                    "type": "json_schema",
                    "json_schema": {"name": "object_captions", "strict": True, "schema": JSON_SCHEMA},
                },
            }
        parts: list[dict[str, Any]] = [{"text": text}]
        if image:
            parts.append({"inline_data": {"mime_type": "image/png", "data": image}})
        return {
            "systemInstruction": {"parts": [{"text": SYSTEM_PROMPT}]},
            "contents": [{"role": "user", "parts": parts}],
            "generationConfig": {
                "temperature": self.config.temperature,
                "responseMimeType": "application/json",
                "responseSchema": GEMINI_SCHEMA,
            },
        }

    def repair_body(self, body: dict[str, Any], bad: str | None, error: str) -> dict[str, Any]:
        """The original request plus the bad answer and what was wrong with it."""
        note = (
            f"Your previous answer was invalid: {error}. Reply again with only a JSON object with the string "
            f"fields short (2-4 words), concise (3-10 words) and detailed (1-2 sentences), nothing else, in the "
            f"form the instructions ask (the name's colour words and noun, no category after it, no size words "
            f"or measurements, no facts about the 3D model, no ids)."
        )
        fixed = json.loads(json.dumps(body))
        if self.provider == "openai":
            if bad is not None:
                fixed["messages"].append({"role": "assistant", "content": bad})
            fixed["messages"].append({"role": "user", "content": note})
        else:
            if bad is not None:
                fixed["contents"].append({"role": "model", "parts": [{"text": bad}]})
            fixed["contents"].append({"role": "user", "parts": [{"text": note}]})
        return fixed

    # --- answers ------------------------------------------------------------------------------------------
    def _content(self, response: httpx.Response) -> str:
        try:
            data = response.json()
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise UnusableAnswerError("response body is not JSON", None) from None
        try:
            if self.provider == "openai":
                choice = data["choices"][0]
                message = choice["message"]
                if message.get("refusal"):
                    raise UnusableAnswerError(self.redact(f"model refused: {message['refusal']}"), None)
                content = message["content"]
                if isinstance(content, list):  # content parts
                    content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
            else:
                candidate = data["candidates"][0]
                content = "".join(p.get("text", "") for p in candidate["content"]["parts"] if isinstance(p, dict))
        except (KeyError, IndexError, TypeError, AttributeError):
            raise UnusableAnswerError("response lacks the answer text (unexpected envelope)", None) from None
        if not isinstance(content, str) or not content.strip():
            raise UnusableAnswerError("empty answer", None)
        return self.redact(content)  # an answer that echoes the key is stored without it

    @staticmethod
    def parse(content: str) -> dict[str, str]:
        """Parse and validate the model's JSON answer (code fences tolerated); ValueError when invalid."""
        text = content.strip()
        fence = re.fullmatch(r"```(?:json)?\s*(.*?)\s*```", text, flags=re.S)
        if fence:
            text = fence.group(1)
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"answer is not valid JSON ({exc.msg} at char {exc.pos})") from None
        return check_tiers(data, LLM_WORD_BOUNDS)

    # --- transport with retries ---------------------------------------------------------------------------
    def _backoff(self, retry_index: int) -> float:
        step = min(self.config.backoff_cap_s, self.config.backoff_base_s * (2.0**retry_index))
        with self._rng_lock:
            jitter = float(self._rng.uniform(0.0, step / 2.0))
        return step / 2.0 + jitter

    def _send(self, body: dict[str, Any], object_id: int, attempts_before: int) -> tuple[str, int]:
        """POST until a 200 arrives or the policy gives up. Returns (answer text, requests made)."""
        made = 0
        last = ""
        for retry in range(self.config.max_retries + 1):
            made += 1
            wait: float | None = None
            try:
                with request_deadline(self.config.timeout_s):
                    response = self.client.post(self.url, json=body, headers=self._headers(),
                                                timeout=self.config.timeout_s)
            except httpx.TimeoutException:
                last = self.redact(f"no complete answer within {self.config.timeout_s:g} s (captions.timeout_s: "
                                   f"connect to last byte) from {self.url}")
            except httpx.TransportError as exc:
                last = self.redact(f"connection error to {self.url}: {type(exc).__name__}: {exc}")
            else:
                status = response.status_code
                if status == 200:
                    try:
                        return self._content(response), made
                    except UnusableAnswerError as bad:
                        bad.attempts = made  # type: ignore[attr-defined]
                        raise
                try:
                    payload: Any = response.json()
                except (json.JSONDecodeError, UnicodeDecodeError):
                    payload = None
                snippet = self.redact(response.text[:300].replace("\n", " "))
                last = f"HTTP {status}: {snippet}"
                if status not in RETRY_STATUSES and status < 500:
                    log.warning("object %d: %s (not retried)", object_id, last)
                    raise CaptionRequestError(last, attempts=attempts_before + made)
                if quota_exhausted(self.provider, payload):
                    log.warning("object %d: quota exhausted (not retried)", object_id)
                    raise CaptionRequestError(f"quota exhausted: {last}", attempts=attempts_before + made)
                hints = [h for h in (parse_retry_after(response.headers), gemini_retry_delay(payload)) if h is not None]
                if hints:
                    wait = max(hints)
                    if wait > self.config.max_retry_after_s:
                        raise CaptionRequestError(
                            f"server asks to wait {wait:g} s (> captions.max_retry_after_s): {last}",
                            attempts=attempts_before + made,
                            retryable=True,
                        )
            if retry == self.config.max_retries:
                break
            delay = wait if wait is not None else self._backoff(retry)
            log.info("object %d: %s; retry %d in %.2f s", object_id, last, retry + 1, delay)
            self._sleep(delay)
        raise CaptionRequestError(
            f"gave up after {made} attempts: {last}", attempts=attempts_before + made, retryable=True
        )

    @staticmethod
    def checked(content: str, item: CaptionInput) -> dict[str, str]:
        """:meth:`parse` plus the caption check (:mod:`mixcount.captions.check`): an answer that appends a
        category, repeats a word, carries an id or source tag, or an absolute size word is invalid too."""
        tiers = HttpCaptioner.parse(content)
        found = blocking(tiers, name=item.name, category=item.category, captioner="http")
        if found:
            raise ValueError("caption check: " + reasons(found))
        return tiers

    def tell_apart(self, item: CaptionInput, others: list[dict[str, str]]) -> CaptionResult | None:
        """Captions of ``item`` again, asked to differ from ``others`` (the equal captions of different
        objects) by what its image shows; None when the answer is invalid or still equal to one of them
        (then the collision stays for the flags). One request, no repair: the first answer was valid."""
        from mixcount.scene.caption_text import normalise_caption

        body = self.build_body(item)
        note = (
            "Other, different objects of this catalog already have exactly these captions: "
            f"{json.dumps(others)}. Write this object's three captions again so that each tier differs from "
            "theirs, with what the image shows that tells this object apart (the colour of a part, a print or "
            "pattern, a material, a shape word); the same rules as before."
        )
        if self.provider == "openai":
            body["messages"].append({"role": "user", "content": note})
        else:
            body["contents"].append({"role": "user", "parts": [{"text": note}]})
        try:
            content, made = self._send(body, item.object_id, 0)
            tiers = self.checked(content, item)
        except (CaptionError, ValueError) as exc:
            log.info("object %d: no telling captions (%s)", item.object_id, self.redact(str(exc)))
            return None
        if any(normalise_caption(tiers[t]) == normalise_caption(o.get(t, "")) for o in others for t in TIERS):
            return None
        return CaptionResult(raw=content, attempts=made, **tiers)

    def caption(self, item: CaptionInput) -> CaptionResult:
        body = self.build_body(item)
        attempts = 0
        try:
            content, made = self._send(body, item.object_id, attempts)
            attempts += made
            try:
                tiers = self.checked(content, item)
                return CaptionResult(raw=content, attempts=attempts, **tiers)
            except ValueError as exc:
                error, bad = str(exc), content
        except UnusableAnswerError as exc:
            attempts += getattr(exc, "attempts", 1)
            error, bad = str(exc), exc.content
        log.info("object %d: invalid answer (%s); one repair attempt", item.object_id, self.redact(error))
        try:
            content, made = self._send(self.repair_body(body, bad, error), item.object_id, attempts)
            attempts += made
            tiers = self.checked(content, item)
        except UnusableAnswerError as exc:
            attempts += getattr(exc, "attempts", 1)
            raise CaptionRequestError(
                self.redact(f"invalid answer after repair: {exc}"), attempts=attempts
            ) from None
        except ValueError as exc:
            raise CaptionRequestError(self.redact(f"invalid answer after repair: {exc}"), attempts=attempts) from None
        return CaptionResult(raw=content, attempts=attempts, **tiers)
