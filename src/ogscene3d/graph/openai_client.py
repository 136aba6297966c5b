"""Minimal OpenAI-compatible HTTP client (chat completions and embeddings) on the standard library.

Works with OpenAI, vLLM, Ollama (``/v1``), LM Studio and any server speaking
``POST {base_url}/chat/completions``.
Every request has a timeout; transient failures (connection errors, timeouts, HTTP 408/429/5xx) are
retried at most ``max_retries`` times with exponential backoff (honouring ``Retry-After`` up to
``max_backoff_s``), so one call takes at most about ``(max_retries + 1) * timeout_s`` plus the backoff.

The API key is read from the environment variable named by ``api_key_env`` at request time; it is only
ever placed in the ``Authorization`` header, never stored on the object, logged, or put in an error.
A missing key is fine for local servers that do not check it.
"""

from __future__ import annotations

import base64
import json
import logging
import os
import re
import time
import urllib.error
import urllib.request
from typing import Any

import numpy as np

from ..errors import ModelError

log = logging.getLogger(__name__)

_RETRY_STATUS = {408, 409, 425, 429, 500, 502, 503, 504}


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
    ) -> None:
        if not base_url or not re.match(r"^https?://", base_url):
            raise ModelError(
                f"OpenAI-compatible endpoint: base_url must start with http:// or https://, got {base_url!r}"
            )
        if not model:
            raise ModelError(
                f"OpenAI-compatible endpoint {base_url}: no model name configured "
                "(set graph.captioner.model / graph.relations.model)"
            )
        if timeout_s <= 0 or max_retries < 0 or backoff_s < 0:
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

    def _post(self, route: str, payload: dict) -> dict:
        url = f"{self.base_url}/{route}"
        body = json.dumps(payload).encode()
        last_error = "no attempt made"
        for attempt in range(self.max_retries + 1):
            headers = {"Content-Type": "application/json", "Accept": "application/json"}
            key = os.environ.get(self.api_key_env or "", "")
            if key:
                headers["Authorization"] = f"Bearer {key}"
            req = urllib.request.Request(url, data=body, headers=headers, method="POST")
            retry_after: float | None = None
            self.calls += 1
            try:
                with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
                    raw = resp.read()
                try:
                    return json.loads(raw)
                except (json.JSONDecodeError, UnicodeDecodeError) as e:
                    raise ModelError(f"{url}: response is not JSON ({e})") from None
            except urllib.error.HTTPError as e:
                detail = _short(e.read() if e.fp is not None else b"")
                last_error = f"HTTP {e.code} {e.reason}: {detail}"
                if e.code not in _RETRY_STATUS:
                    raise ModelError(f"{url}: {last_error}") from None
                ra = e.headers.get("Retry-After") if e.headers is not None else None
                try:
                    retry_after = float(ra) if ra is not None else None
                except ValueError:
                    retry_after = None
            except TimeoutError as e:
                last_error = f"timed out after {self.timeout_s:g} s ({e})"
            except urllib.error.URLError as e:
                last_error = f"connection failed ({e.reason})"
            except (ConnectionError, OSError) as e:
                last_error = f"connection failed ({e})"
            if attempt < self.max_retries:
                delay = self.backoff_s * (2.0**attempt) if retry_after is None else retry_after
                delay = min(delay, self.max_backoff_s)
                log.warning(
                    "%s: %s; retry %d/%d in %.1f s", url, last_error, attempt + 1, self.max_retries, delay
                )
                time.sleep(delay)
        raise ModelError(f"{url}: {last_error} (gave up after {self.max_retries + 1} attempts)")

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
