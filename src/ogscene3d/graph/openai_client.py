"""Minimal OpenAI-compatible HTTP client (chat completions and embeddings) on the standard library.

Works with OpenAI, vLLM, Ollama (``/v1``), LM Studio and any server speaking
``POST {base_url}/chat/completions``.
Every request has a timeout; transient failures (connection errors, timeouts, HTTP 408/429/5xx) are
retried at most ``max_retries`` times with exponential backoff (honouring ``Retry-After`` up to
``max_backoff_s``), so one call takes at most about ``(max_retries + 1) * timeout_s`` plus the backoff.
``timeout_s`` bounds a whole attempt (connecting, sending, the status line, headers and body), not just
each socket read: a server that trickles its reply byte by byte is cut off at the deadline.

The API key is read from the environment variable named by ``api_key_env`` at request time; it is only
ever placed in the ``Authorization`` header, never stored on the object, logged, or put in an error.
A missing key is fine for local servers that do not check it, but is warned about once (naming the
variable) and mentioned in HTTP 401/403 errors; ``api_key_env: ""`` means "no key" and is not warned about.
"""

from __future__ import annotations

import base64
import http.client
import json
import logging
import os
import re
import socket
import threading
import time
import urllib.error
import urllib.request
from typing import Any

import numpy as np

from ..errors import ModelError

log = logging.getLogger(__name__)

_RETRY_STATUS = {408, 409, 425, 429, 500, 502, 503, 504}
_AUTH_STATUS = {401, 403}

# (variable, endpoint) pairs already warned about: the captioner, the relations LLM and the query
# embeddings each have a client, and one warning per endpoint is enough.
_warned_unset_keys: set[tuple[str, str]] = set()
_warn_lock = threading.Lock()


class EndpointUnreachable(ModelError):
    """Every attempt of a request failed to connect or timed out (no HTTP answer came back).

    Callers that make many requests in a row (the captioner) stop after a few of these instead of
    waiting out the timeout of each one."""


class _Failure(Exception):
    """One failed attempt: what to report, whether to retry, and whether the server answered at all."""

    def __init__(
        self, message: str, retryable: bool = True, unreachable: bool = True, retry_after: float | None = None
    ) -> None:
        super().__init__(message)
        self.message = message
        self.retryable = retryable
        self.unreachable = unreachable
        self.retry_after = retry_after


class _Deadline:
    """Shuts the attempt's socket down once ``seconds`` have passed.

    urllib's ``timeout`` bounds each socket read, so a server sending a byte every 0.1 s would never time
    out; shutting the socket down from a timer wakes the blocked read and bounds the whole attempt.
    """

    def __init__(self, seconds: float) -> None:
        self.expired = False
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self._timer = threading.Timer(seconds, self._expire)
        self._timer.daemon = True
        self._timer.start()

    def watch(self, sock: socket.socket) -> None:
        """Called with each connection's socket as soon as it is connected."""
        with self._lock:
            self._sock = sock
            if self.expired:  # the deadline passed while connecting
                _shutdown(sock)

    def _expire(self) -> None:
        with self._lock:
            self.expired = True
            if self._sock is not None:
                _shutdown(self._sock)

    def cancel(self) -> None:
        self._timer.cancel()


def _shutdown(sock: socket.socket) -> None:
    try:
        # The plain socket's shutdown, also for TLS sockets: it wakes the reading thread without
        # dropping the TLS state that thread is still using (SSLSocket.shutdown would).
        socket.socket.shutdown(sock, socket.SHUT_RDWR)
    except OSError:
        pass  # already closed: the attempt has finished


class _DeadlineHandlerMixin:
    """A urllib handler part that hands every new connection's socket to the attempt's deadline."""

    deadline: _Deadline

    def do_open(self, http_class, req, **kwargs):
        deadline = self.deadline

        class _Connection(http_class):  # type: ignore[misc, valid-type]
            def connect(self) -> None:
                super().connect()
                deadline.watch(self.sock)

        return super().do_open(_Connection, req, **kwargs)  # type: ignore[misc]


class _HTTPHandler(_DeadlineHandlerMixin, urllib.request.HTTPHandler):
    pass


class _HTTPSHandler(_DeadlineHandlerMixin, urllib.request.HTTPSHandler):
    pass


def _opener(deadline: _Deadline) -> urllib.request.OpenerDirector:
    """urllib's default opener (proxies from the environment included) with deadline-aware handlers."""
    handlers = [_HTTPHandler(), _HTTPSHandler()]
    for h in handlers:
        h.deadline = deadline
    return urllib.request.build_opener(*handlers)


def _retry_after(e: urllib.error.HTTPError) -> float | None:
    ra = e.headers.get("Retry-After") if e.headers is not None else None
    try:
        return float(ra) if ra is not None else None
    except ValueError:
        return None  # an HTTP date: use the normal backoff


class ChatClient:
    """OpenAI-compatible chat-completions / embeddings client.

    ``base_url`` is the API root including the version (e.g. ``http://127.0.0.1:8000/v1``).
    """

    def __init__(
        self,
        base_url: str,
        model: str,
        api_key_env: str = "OPENAI_API_KEY",
        timeout_s: float = 30.0,
        max_retries: int = 2,
        backoff_s: float = 1.0,
        max_backoff_s: float = 8.0,
        model_setting: str = "graph.captioner.model / graph.relations.model",
    ) -> None:
        """``model_setting`` names the config key that gives ``model``, for the error when it is empty (the
        captioner, the relations LLM and the query embeddings each read their own)."""
        if not base_url or not re.match(r"^https?://", base_url):
            raise ModelError(
                f"OpenAI-compatible endpoint: base_url must start with http:// or https://, got {base_url!r}"
            )
        if not model:
            raise ModelError(
                f"OpenAI-compatible endpoint {base_url}: no model name configured (set {model_setting})"
            )
        if not timeout_s > 0 or max_retries < 0 or backoff_s < 0:
            raise ModelError(
                f"OpenAI-compatible endpoint: need timeout_s > 0, max_retries >= 0, backoff_s >= 0 "
                f"(got {timeout_s}, {max_retries}, {backoff_s})"
            )
        self.base_url = base_url.rstrip("/")
        self.model = model
        self.api_key_env = api_key_env
        self.timeout_s = float(timeout_s)
        self.max_retries = int(max_retries)
        self.backoff_s = float(backoff_s)
        self.max_backoff_s = float(max_backoff_s)
        self.calls = 0  # HTTP requests made (attempts), for timings/tests

    def __repr__(self) -> str:  # never shows the key (it is not stored anyway)
        return (
            f"ChatClient(base_url={self.base_url!r}, model={self.model!r}, api_key_env={self.api_key_env!r})"
        )

    def _api_key(self) -> str:
        """The key from ``$api_key_env`` (read per request); warns once per endpoint when it is unset."""
        if not self.api_key_env:
            return ""  # explicitly no key: nothing to warn about
        key = os.environ.get(self.api_key_env, "")
        if not key:
            with _warn_lock:
                first = (self.api_key_env, self.base_url) not in _warned_unset_keys
                _warned_unset_keys.add((self.api_key_env, self.base_url))
            if first:
                log.warning(
                    "%s: environment variable %s (api_key_env) is not set; sending requests without an "
                    'API key (fine for a local server that does not check one; set api_key_env to "" '
                    "to say so)",
                    self.base_url,
                    self.api_key_env,
                )
        return key

    def _key_hint(self, key: str) -> str:
        """Appended to 401/403 errors: which variable the key came from (never the key itself)."""
        if not self.api_key_env:
            return " (no API key sent: api_key_env is empty)"
        return f" (API key from ${self.api_key_env}{'' if key else ': not set'})"

    def _timed_out(self) -> str:
        return f"timed out after {self.timeout_s:g} s"

    def _post(self, route: str, payload: dict) -> dict:
        url = f"{self.base_url}/{route}"
        body = json.dumps(payload).encode()
        key = self._api_key()
        last_error = "no attempt made"
        unreachable = True  # no attempt got an HTTP answer
        for attempt in range(self.max_retries + 1):
            self.calls += 1
            try:
                raw = self._attempt(url, body, key)
            except _Failure as f:
                last_error, unreachable = f.message, unreachable and f.unreachable
                if not f.retryable:
                    raise ModelError(f"{url}: {last_error}") from None
                retry_after = f.retry_after
            else:
                try:
                    return json.loads(raw)
                except (json.JSONDecodeError, UnicodeDecodeError) as e:
                    raise ModelError(f"{url}: response is not JSON ({e})") from None
            if attempt < self.max_retries:
                delay = self.backoff_s * (2.0**attempt) if retry_after is None else retry_after
                delay = min(delay, self.max_backoff_s)
                log.warning(
                    "%s: %s; retry %d/%d in %.1f s", url, last_error, attempt + 1, self.max_retries, delay
                )
                time.sleep(delay)
        error = EndpointUnreachable if unreachable else ModelError
        raise error(f"{url}: {last_error} (gave up after {self.max_retries + 1} attempts)")

    def _attempt(self, url: str, body: bytes, key: str) -> bytes:
        """One POST within ``timeout_s`` in all; the raw response body, or :class:`_Failure`."""
        headers = {"Content-Type": "application/json", "Accept": "application/json"}
        if key:
            headers["Authorization"] = f"Bearer {key}"
        req = urllib.request.Request(url, data=body, headers=headers, method="POST")
        deadline = _Deadline(self.timeout_s)
        try:
            with _opener(deadline).open(req, timeout=self.timeout_s) as resp:
                raw = resp.read()
            if deadline.expired:  # a body without Content-Length cut short looks complete
                raise _Failure(self._timed_out())
            return raw
        except urllib.error.HTTPError as e:
            try:
                detail = _short(e.read() if e.fp is not None else b"")
            except (OSError, http.client.HTTPException):
                detail = "(body unreadable)"
            if deadline.expired:
                raise _Failure(self._timed_out()) from None
            message = f"HTTP {e.code} {e.reason}: {detail}"
            if e.code in _AUTH_STATUS:
                message += self._key_hint(key)
            raise _Failure(
                message, e.code in _RETRY_STATUS, unreachable=False, retry_after=_retry_after(e)
            ) from None
        except _Failure:
            raise
        except TimeoutError as e:
            raise _Failure(f"{self._timed_out()} ({e})") from None
        except urllib.error.URLError as e:
            if deadline.expired:
                raise _Failure(self._timed_out()) from None
            raise _Failure(f"connection failed ({e.reason})") from None
        except (OSError, http.client.HTTPException) as e:
            if deadline.expired:
                raise _Failure(self._timed_out()) from None
            # an HTTPException is a broken answer (cut short, bad status line): the server is there
            unreachable = isinstance(e, OSError)
            raise _Failure(f"connection failed ({type(e).__name__}: {e})", unreachable=unreachable) from None
        finally:
            deadline.cancel()

    def chat(
        self,
        messages: list[dict[str, Any]],
        max_tokens: int | None = None,
        temperature: float = 0.0,
    ) -> str:
        """Send one chat completion and return the assistant's text. ModelError on failure."""
        payload: dict[str, Any] = {"model": self.model, "messages": messages, "temperature": temperature}
        if max_tokens:
            payload["max_tokens"] = int(max_tokens)
        data = self._post("chat/completions", payload)
        try:
            content = data["choices"][0]["message"]["content"]
        except (KeyError, IndexError, TypeError):
            raise ModelError(
                f"{self.base_url}/chat/completions: unexpected response layout {_short(data)}"
            ) from None
        if isinstance(content, list):  # content parts
            content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
        if not isinstance(content, str):
            raise ModelError(f"{self.base_url}/chat/completions: message content is not text")
        return content

    def embed(self, texts: list[str], model: str | None = None) -> np.ndarray:
        """Embeddings [len(texts), D] float32 from ``POST {base_url}/embeddings``. ModelError on failure."""
        data = self._post("embeddings", {"model": model or self.model, "input": list(texts)})
        try:
            items = sorted(data["data"], key=lambda d: d.get("index", 0))
            out = np.asarray([d["embedding"] for d in items], dtype=np.float32)
        except (KeyError, TypeError, ValueError):
            raise ModelError(
                f"{self.base_url}/embeddings: unexpected response layout {_short(data)}"
            ) from None
        if out.ndim != 2 or len(out) != len(texts) or not np.all(np.isfinite(out)):
            raise ModelError(
                f"{self.base_url}/embeddings: expected {len(texts)} finite vectors, got {out.shape}"
            )
        return out


def _short(obj: Any, n: int = 200) -> str:
    text = obj.decode("utf-8", "replace") if isinstance(obj, bytes) else str(obj)
    return text if len(text) <= n else text[:n] + "..."


def image_data_url(rgb: np.ndarray, quality: int = 90) -> str:
    """Encode a uint8 RGB [H, W, 3] image as a ``data:image/jpeg;base64,...`` URL."""
    import cv2

    img = np.asarray(rgb)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"image_data_url: expected non-empty uint8 HxWx3 RGB, got {img.dtype} {img.shape}")
    ok, buf = cv2.imencode(
        ".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    )
    if not ok:
        raise ValueError("image_data_url: JPEG encoding failed")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def extract_json(text: str) -> Any:
    """Parse the JSON object or array in a model reply (tolerates ```json fences and prose around it).

    Raises ValueError when there is none.
    """
    t = text.strip()
    fence = re.search(r"```(?:json)?\s*(.*?)```", t, flags=re.S)
    if fence:
        t = fence.group(1).strip()
    try:
        return json.loads(t)
    except json.JSONDecodeError:
        pass
    for open_c, close_c in (("{", "}"), ("[", "]")):
        i, j = t.find(open_c), t.rfind(close_c)
        if i != -1 and j > i:
            try:
                return json.loads(t[i : j + 1])
            except json.JSONDecodeError:
                continue
    raise ValueError(f"no JSON found in model reply: {_short(text)!r}")
