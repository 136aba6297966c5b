"""OpenAI-compatible chat completions and embeddings through the official ``openai`` package.

Works with OpenAI, vLLM, Ollama (``/v1``), LM Studio and any server speaking
``POST {base_url}/chat/completions``. The SDK retries connection errors, timeouts and HTTP 408/409/429/5xx
at most ``max_retries`` times with its exponential backoff (honouring ``Retry-After``). Each attempt is
bounded by ``timeout_s`` in all (connecting, the status line, headers and body), not per socket read as
the SDK's own timeout is: a server that trickles its reply byte by byte is cut off at the deadline, so one
call takes at most about ``(max_retries + 1) * timeout_s`` plus the backoff.

The API key is read from the environment variable named by ``api_key_env`` at request time and only put
in that request's ``Authorization`` header; it is never stored on the object. A server may echo it back
(some proxies put the request headers into their 401 page): every error raised here and every record that
this module, the SDK and its HTTP library log is scrubbed of the keys in use. A missing key is fine for
local servers that do not check it, but is warned about once (naming the variable) and mentioned in HTTP
401/403 errors; ``api_key_env: ""`` means "no key" and is not warned about.
"""

from __future__ import annotations

import base64
import json
import logging
import os
import re
import socket
import threading
import urllib.parse
import urllib.request
from typing import Any

import numpy as np

from ..config import EndpointConfig
from ..errors import ModelError

log = logging.getLogger(__name__)

_AUTH_STATUS = {401, 403}
# retried by the SDK; still failing after the retries, the server is not serving (counts for the
# captioner's circuit breaker like an unreachable one)
_UNAVAILABLE_STATUS = {408, 409, 425, 429}

# (variable, endpoint) pairs already warned about: the captioner, the relations LLM and the query
# embeddings each have a client, and one warning per endpoint is enough.
_warned_unset_keys: set[tuple[str, str]] = set()
_warn_lock = threading.Lock()

# keys sent so far in this process, scrubbed from errors and log records
_secrets: set[str] = set()
_secrets_lock = threading.Lock()
REDACTED = "[REDACTED]"


def redact(text: str) -> str:
    """``text`` with every API key this process has sent replaced by ``[REDACTED]``."""
    with _secrets_lock:
        keys = sorted(_secrets, key=len, reverse=True)
    for k in keys:
        text = text.replace(k, REDACTED)
    return text


class _RedactFilter(logging.Filter):
    """Scrubs API keys from a log record's message (formatted with its arguments)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not _secrets:
            return True
        try:
            message = record.getMessage()
        except Exception:  # a malformed record: leave it to logging's own error report
            return True
        clean = redact(message)
        if clean != message:
            record.msg, record.args = clean, None
        if record.exc_info and record.exc_info[1] is not None:
            text = redact(logging.Formatter().formatException(record.exc_info))
            record.exc_info, record.exc_text = None, text
        return True


_FILTER = _RedactFilter()
_GUARDED_PACKAGES = ("ogscene3d", "openai", "httpx2", "httpcore2")


def _guard_loggers() -> None:
    """Puts the redacting filter on every logger of this package, the SDK and its HTTP library. A
    logger's filters see only the records logged on that logger itself, not on its children, hence each
    one; called once those packages are imported (they create their loggers at import)."""
    for name, logger in list(logging.root.manager.loggerDict.items()):
        if isinstance(logger, logging.Logger) and name.split(".")[0] in _GUARDED_PACKAGES:
            logger.addFilter(_FILTER)  # a no-op where it is already there


def _remember_key(key: str) -> None:
    if key:
        with _secrets_lock:
            _secrets.add(key)


class EndpointUnreachable(ModelError):
    """Every attempt of a request failed to connect or timed out (no HTTP answer came back).

    Callers that make many requests in a row (the captioner) stop after a few of these instead of
    waiting out the timeout of each one."""


class EndpointUnavailable(ModelError):
    """The server answered every attempt, but only with a server-side failure (HTTP 5xx, 429, 408...).

    For the captioner's circuit breaker this is as bad as no answer: each further request would wait
    out the same retries."""


class _Deadline:
    """Shuts the attempt's socket down once ``seconds`` have passed.

    The HTTP library's timeouts bound each socket read, so a server sending a byte every 0.1 s would
    never time out; shutting the socket down from a timer wakes the blocked read and bounds the attempt.
    """

    def __init__(self, seconds: float) -> None:
        self.expired = False
        self._socks: list[socket.socket] = []
        self._lock = threading.Lock()
        self._timer = threading.Timer(seconds, self._expire)
        self._timer.daemon = True
        self._timer.start()

    def watch(self, sock: socket.socket) -> None:
        """Called with each connection's socket as soon as it is connected."""
        with self._lock:
            self._socks.append(sock)
            if self.expired:  # the deadline passed while connecting
                _shutdown(sock)

    def _expire(self) -> None:
        with self._lock:
            self.expired = True
            for s in self._socks:
                _shutdown(s)

    def cancel(self) -> None:
        self._timer.cancel()


def _shutdown(sock: socket.socket) -> None:
    try:
        # The plain socket's shutdown, also for TLS sockets: it wakes the reading thread without
        # dropping the TLS state that thread is still using (SSLSocket.shutdown would).
        socket.socket.shutdown(sock, socket.SHUT_RDWR)
    except OSError:
        pass  # already closed: the attempt has finished


def _env_proxy(base_url: str) -> str | None:
    """The proxy the environment names for ``base_url`` (a custom transport does not read it itself)."""
    parts = urllib.parse.urlsplit(base_url)
    if parts.hostname and urllib.request.proxy_bypass(parts.hostname):
        return None
    return urllib.request.getproxies().get(parts.scheme)


def _transport(client: ChatClient):
    """An httpx transport that counts attempts and bounds each one to ``client.timeout_s`` in all."""
    import httpx2

    class _AttemptTransport(httpx2.BaseTransport):
        def __init__(self) -> None:
            # no kept-alive connections: each attempt connects, so its socket is known to its deadline
            self._inner = httpx2.HTTPTransport(
                limits=httpx2.Limits(max_keepalive_connections=0), proxy=_env_proxy(client.base_url)
            )

        def handle_request(self, request):
            client._count_attempt()
            deadline = _Deadline(client.timeout_s)

            def trace(name: str, info: dict) -> None:
                if name.endswith("connect_tcp.complete") and info.get("return_value") is not None:
                    sock = info["return_value"].get_extra_info("socket")
                    if sock is not None:
                        deadline.watch(sock)

            request.extensions = {**request.extensions, "trace": trace}
            timed_out = httpx2.ReadTimeout(client._timed_out(), request=request)
            try:
                response = self._inner.handle_request(request)
                try:
                    body = response.read()
                finally:
                    response.close()
            except httpx2.TransportError:
                if deadline.expired:
                    raise timed_out from None
                raise
            finally:
                deadline.cancel()
            if deadline.expired:  # a body without Content-Length cut short looks complete
                raise timed_out
            return httpx2.Response(
                response.status_code,
                headers=response.headers,
                content=body,
                request=request,
                extensions=response.extensions,
            )

        def close(self) -> None:
            self._inner.close()

    return _AttemptTransport()


class ChatClient:
    """OpenAI-compatible chat-completions / embeddings client on the ``openai`` package.

    ``base_url`` is the API root including the version (e.g. ``http://127.0.0.1:8000/v1``).
    """

    def __init__(
        self,
        base_url: str,
        model: str,
        api_key_env: str = "OPENAI_API_KEY",
        timeout_s: float = 30.0,
        max_retries: int = 2,
        model_setting: str = "graph.endpoint.model",
    ) -> None:
        """``model_setting`` names the config key that gives ``model``, for the error when it is empty (each
        component can name its own model beside the endpoint's)."""
        if not base_url or not re.match(r"^https?://", base_url):
            raise ModelError(
                f"OpenAI-compatible endpoint: base_url must start with http:// or https://, got {base_url!r}"
            )
        if not model:
            raise ModelError(
                f"OpenAI-compatible endpoint {base_url}: no model name configured (set {model_setting})"
            )
        if not timeout_s > 0 or max_retries < 0:
            raise ModelError(
                f"OpenAI-compatible endpoint: need timeout_s > 0 and max_retries >= 0 "
                f"(got {timeout_s}, {max_retries})"
            )
        self.base_url = base_url.rstrip("/")
        self.model = model
        self.api_key_env = api_key_env
        self.timeout_s = float(timeout_s)
        self.max_retries = int(max_retries)
        self.calls = 0  # HTTP requests made (attempts), for timings/tests
        self._calls_lock = threading.Lock()
        self._sdk_client: Any = None
        self._sdk_lock = threading.Lock()

    @classmethod
    def from_config(cls, endpoint: EndpointConfig, model: str = "", model_setting: str = "") -> ChatClient:
        """A client of the endpoint ``endpoint`` (``graph.endpoint``) that asks for ``model``, a component's
        own (``""``: the endpoint's).

        Args:
            endpoint: base URL, default model, API key variable, timeout and retries.
            model: the model the component names in its own section; ``""`` for ``endpoint.model``.
            model_setting: the key that gave ``model`` (e.g. ``"graph.captioner.model"``), named in the error
                when neither gives a model.

        Returns:
            The client (no request made yet).
        """
        setting = f"{model_setting} or graph.endpoint.model" if model_setting else "graph.endpoint.model"
        return cls(endpoint.base_url, model or endpoint.model, endpoint.api_key_env, endpoint.timeout_s,
                   endpoint.max_retries, model_setting=setting)  # fmt: skip

    def __repr__(self) -> str:  # never shows the key (it is not stored anyway)
        return (
            f"ChatClient(base_url={self.base_url!r}, model={self.model!r}, api_key_env={self.api_key_env!r})"
        )

    def _count_attempt(self) -> None:
        with self._calls_lock:
            self.calls += 1

    def _sdk(self):
        """The ``openai.OpenAI`` client (built on first use). Its own key is a placeholder that is never
        sent: each request sets or omits ``Authorization`` itself, with the key read at that moment."""
        with self._sdk_lock:  # the captioner's threads share one client
            if self._sdk_client is None:
                self._sdk_client = self._build_sdk()
        return self._sdk_client

    def _build_sdk(self):
        try:
            import httpx2
            import openai
        except ImportError as e:
            raise ModelError(
                f"OpenAI-compatible endpoint {self.base_url}: the openai package is missing ({e}); "
                "pip install openai (or pip install 'ogscene3d[llm]')"
            ) from None
        sdk = openai.OpenAI(
            base_url=self.base_url,
            api_key="set-per-request",
            timeout=self.timeout_s,
            max_retries=self.max_retries,
            http_client=httpx2.Client(transport=_transport(self), timeout=self.timeout_s),
        )
        import httpcore2  # noqa: F401  (its loggers exist once it is imported)

        _guard_loggers()
        return sdk

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
        _remember_key(key)
        return key

    def _key_hint(self, key: str) -> str:
        """Appended to 401/403 errors: which variable the key came from (never the key itself)."""
        if not self.api_key_env:
            return " (no API key sent: api_key_env is empty)"
        return f" (API key from ${self.api_key_env}{'' if key else ': not set'})"

    def _timed_out(self) -> str:
        return f"timed out after {self.timeout_s:g} s"

    def _request(self, route: str, call) -> Any:
        """Runs ``call(sdk, extra_headers)`` (one SDK request, retries included) and turns the SDK's
        exceptions into :class:`ModelError` (:class:`EndpointUnreachable` / :class:`EndpointUnavailable`
        when every attempt failed that way), scrubbed of the key and not chained to the SDK's exception
        (whose response body may hold the echoed key)."""
        sdk = self._sdk()  # first: a missing openai package is named here
        import openai

        url = f"{self.base_url}/{route}"
        key = self._api_key()
        headers = {"Authorization": f"Bearer {key}" if key else openai.Omit()}
        gave_up = f"(gave up after {self.max_retries + 1} attempts)"
        error: ModelError
        try:
            return call(sdk, headers)
        except openai.APITimeoutError:
            error = EndpointUnreachable(f"{url}: {self._timed_out()} {gave_up}")
        except openai.APIConnectionError as e:
            cause = e.__cause__ or e.__context__
            detail = f"{type(cause).__name__}: {cause}" if cause is not None else str(e)
            error = EndpointUnreachable(f"{url}: connection failed ({detail}) {gave_up}")
        except openai.APIStatusError as e:
            status = e.status_code
            message = f"{url}: HTTP {status} {_reason(e)}: {_short(_body_text(e))}"
            if status in _AUTH_STATUS:
                error = ModelError(message + self._key_hint(key))
            elif status >= 500 or status in _UNAVAILABLE_STATUS:
                error = EndpointUnavailable(f"{message} {gave_up}")
            else:
                error = ModelError(message)
        except openai.APIResponseValidationError as e:
            error = ModelError(f"{url}: unexpected response ({_short(str(e))})")
        except openai.OpenAIError as e:
            error = ModelError(f"{url}: {type(e).__name__}: {_short(str(e))}")
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            error = ModelError(f"{url}: response is not JSON ({e})")
        raise type(error)(redact(str(error))) from None

    def chat(
        self,
        messages: list[dict[str, Any]],
        max_tokens: int | None = None,
        temperature: float = 0.0,
    ) -> str:
        """Send one chat completion and return the assistant's text. ModelError on failure."""
        extra: dict[str, Any] = {"max_tokens": int(max_tokens)} if max_tokens else {}

        def call(sdk, headers):
            return sdk.chat.completions.with_raw_response.create(
                model=self.model,
                messages=messages,
                temperature=temperature,
                extra_headers=headers,
                **extra,
            )

        data = self._json(self._request("chat/completions", call), "chat/completions")
        try:
            content = data["choices"][0]["message"]["content"]
        except (KeyError, IndexError, TypeError):
            raise ModelError(
                redact(f"{self.base_url}/chat/completions: unexpected response layout {_short(data)}")
            ) from None
        if isinstance(content, list):  # content parts
            content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
        if not isinstance(content, str):
            raise ModelError(f"{self.base_url}/chat/completions: message content is not text")
        return content

    def embed(self, texts: list[str], model: str | None = None) -> np.ndarray:
        """Embeddings [len(texts), D] float32 from ``POST {base_url}/embeddings``. ModelError on failure."""

        def call(sdk, headers):
            return sdk.embeddings.with_raw_response.create(
                model=model or self.model, input=list(texts), encoding_format="float", extra_headers=headers
            )

        data = self._json(self._request("embeddings", call), "embeddings")
        try:
            items = sorted(data["data"], key=lambda d: d.get("index", 0))
            out = np.asarray([d["embedding"] for d in items], dtype=np.float32)
        except (KeyError, TypeError, ValueError, AttributeError):
            raise ModelError(
                redact(f"{self.base_url}/embeddings: unexpected response layout {_short(data)}")
            ) from None
        if out.ndim != 2 or len(out) != len(texts) or not np.all(np.isfinite(out)):
            raise ModelError(
                f"{self.base_url}/embeddings: expected {len(texts)} finite vectors, got {out.shape}"
            )
        return out

    def _json(self, raw: Any, route: str) -> Any:
        """The reply's JSON, read as sent: servers that are only OpenAI-like (a missing ``id`` or
        ``object``) still work, and the layout is checked by the caller."""
        try:
            return json.loads(raw.http_response.content)
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise ModelError(f"{self.base_url}/{route}: response is not JSON ({e})") from None


def _reason(e: Any) -> str:
    try:
        return e.response.reason_phrase
    except Exception:
        return ""


def _body_text(e: Any) -> str:
    try:
        return e.response.text
    except Exception:
        return str(e.body)


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
