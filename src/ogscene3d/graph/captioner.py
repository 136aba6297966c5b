"""Node captions and tags (paper Eqs. 18 and 23) behind the :class:`Captioner` protocol.

* :class:`OpenAICaptioner`: a VLM through the OpenAI-compatible chat-completions API. One request per node
  with its observation set O_i (context crop, then up to three masked views, as base64 JPEG data URLs)
  and the caption prompt; then ONE request that turns all new captions into short tags. A prose reply
  (no JSON) is kept, marked ``"vlm-text"``; after a few requests in a row that cannot reach the endpoint
  or that it answers only with server errors (HTTP 5xx, 429) after the retries, the rest of the update's
  requests are skipped.
* :class:`HeuristicCaptioner`: offline; says only what geometry and colour support (floor / wall / ceiling
  from the node's plane normal, extent and height along the configured up vector; otherwise size, colour
  and flatness) and marks its captions as heuristic.
* :class:`GroundTruthCaptioner`: names from ground truth (synthetic scenes, evaluation only).

A captioner returns ``{node id: Description}`` for the nodes it could describe; a node it leaves out keeps
its previous caption (the scene graph fills nodes that never had one with the heuristic captioner, and asks
the captioner again at its next update while a node's caption is a heuristic one).
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol, runtime_checkable

from ..config import CaptionerConfig, EndpointConfig
from ..errors import ConfigError
from .geometry import color_name, format_length
from .openai_client import (
    ChatClient,
    EndpointUnavailable,
    EndpointUnreachable,
    extract_json,
    image_data_url,
)
from .types import CaptionRequest, Description

log = logging.getLogger(__name__)


@runtime_checkable
class Captioner(Protocol):
    """Describes nodes. Implementations must not raise for a single node's failure; leave it out instead."""

    def describe(self, requests: Sequence[CaptionRequest]) -> dict[int, Description]: ...


CAPTION_SYSTEM_PROMPT = (
    "You are a vision assistant that describes entities in 3D indoor scenes for a robot's scene graph."
)

CAPTION_PROMPT = (
    "The images show one entity of an indoor scene. The first image is a crop centred on the entity that "
    "keeps its surroundings, for context. The other images show only the entity, everything else masked "
    "out in black, seen from different viewpoints. Using all views together, say what the entity is, its "
    "main attributes (colour, material, shape, parts) and its role in the scene. It may be a piece of "
    "furniture, an object, or a structural element such as a wall, floor, ceiling, door or window. "
    'Answer with JSON only: {"caption": "<one or two sentences>"}'
)

TAG_PROMPT = (
    "Below are captions of entities in a 3D indoor scene, each with an id. For each caption give a short "
    "tag: the entity's category as a lowercase singular noun phrase of one to three words (for example "
    '"chair", "coffee table", "wall"). Answer with JSON only: {"tags": {"<id>": "<tag>", ...}}'
)


def read_caption_reply(text: str, max_chars: int = 1000) -> tuple[str | None, bool]:
    """``(caption, is_json)`` of a VLM reply: ``{"caption": ...}`` gives ``(caption, True)``, plain prose
    ``(prose, False)`` (local VLMs often ignore the requested format, so prose is kept); the caption is
    None when the reply is malformed, empty or longer than ``max_chars``. A reply that attempts JSON but
    does not parse (typically cut off at ``max_tokens``: ``{"caption": "a wooden ch``) is malformed, not
    prose: keeping it would store JSON debris as a VLM caption that is never asked for again."""
    caption: object = None
    is_json = True
    try:
        data = extract_json(text)
        if not isinstance(data, dict):
            return None, True
        caption = data.get("caption")
    except ValueError:
        t = text.strip()
        if t[:1] in ("{", "[") or t.startswith("```") or re.search(r'"caption"\s*:', t):
            return None, True
        caption, is_json = text, False
    if not isinstance(caption, str):
        return None, is_json
    caption = " ".join(caption.split())
    if not caption or len(caption) > max_chars:
        return None, is_json
    return caption, is_json


def parse_caption_reply(text: str, max_chars: int = 1000) -> str | None:
    """The caption in a VLM reply (``{"caption": ...}`` or plain prose); None when malformed or empty."""
    return read_caption_reply(text, max_chars)[0]


def parse_tag_reply(text: str, ids: Sequence[int]) -> dict[int, str]:
    """``{id: tag}`` from a tag-prompt reply; entries that are missing or not short strings are dropped."""
    try:
        data = extract_json(text)
    except ValueError as e:
        log.warning("tag LLM: %s", e)
        return {}
    tags = data.get("tags", data) if isinstance(data, dict) else data
    if isinstance(tags, list):  # [{"id": 3, "tag": "chair"}]
        tags = {str(t.get("id")): t.get("tag") for t in tags if isinstance(t, dict)}
    if not isinstance(tags, dict):
        log.warning("tag LLM: reply has no 'tags' mapping")
        return {}
    out: dict[int, str] = {}
    wanted = {int(i) for i in ids}
    for k, v in tags.items():
        try:
            i = int(str(k).strip())
        except ValueError:
            continue
        if i in wanted and isinstance(v, str) and 0 < len(v.strip()) <= 60:
            out[i] = " ".join(v.strip().lower().split())
    return out


def tag_from_caption(caption: str) -> str:
    """Fallback tag when the tag request fails: the caption's first clause, at most four words."""
    head = caption.split(".")[0].split(",")[0].strip().lower()
    for article in ("a ", "an ", "the ", "this is a ", "this is an ", "it is a ", "it is an "):
        if head.startswith(article):
            head = head[len(article) :]
    return " ".join(head.split()[:4]) or "object"


class _CircuitBreaker:
    """Counts consecutive requests of one ``describe`` call that the endpoint did not serve (connection
    failed, timed out, or only server errors such as HTTP 500/503/429 after the retries); once ``limit``
    of them came in a row, the remaining requests are skipped: with the server down or failing, each
    would otherwise wait out its own timeouts and retries while mapping waits. A client error (HTTP 4xx,
    a malformed reply) is the request's own fault and does not count."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.failures = 0
        self.skipped = 0
        self.tripped = False
        self._lock = threading.Lock()

    def allow(self) -> bool:
        with self._lock:
            if self.tripped:
                self.skipped += 1
            return not self.tripped

    def record(self, unserved: bool) -> None:
        with self._lock:
            self.failures = self.failures + 1 if unserved else 0
            self.tripped = self.tripped or self.failures >= self.limit


class OpenAICaptioner:
    """VLM captions through an OpenAI-compatible chat-completions endpoint, tags in one batched call.

    Nodes without any stored observation are left out (no images, nothing for the VLM to see).
    Per-node requests run on up to ``concurrency`` threads; failures are logged and the node left out.
    After ``max_consecutive_failures`` requests in a row that the endpoint did not serve (unreachable, or
    server errors after the retries), the rest of the call's requests are skipped (one warning); the
    scene graph asks again at its next update.
    Captions from replies that are prose instead of the requested JSON get source ``"vlm-text"`` (warned
    once per captioner: a refusal would be kept as a caption too).
    """

    def __init__(
        self,
        client: ChatClient,
        max_tokens: int = 300,
        concurrency: int = 4,
        tag_client: ChatClient | None = None,
        max_consecutive_failures: int = 3,
    ):
        self.client = client
        self.tag_client = tag_client or client
        self.max_tokens = max_tokens
        self.concurrency = max(1, int(concurrency))
        self.max_consecutive_failures = max(1, int(max_consecutive_failures))
        self._warned_prose = False
        self._lock = threading.Lock()

    @classmethod
    def from_config(cls, config: CaptionerConfig, endpoint: EndpointConfig | None = None) -> OpenAICaptioner:
        """From ``graph.captioner`` and the endpoint it calls (``graph.endpoint``; None: the defaults)."""
        client = ChatClient.from_config(endpoint or EndpointConfig(), config.model, "graph.captioner.model")
        return cls(client, config.max_tokens, config.concurrency)

    def caption_messages(self, req: CaptionRequest) -> list[dict]:
        """The chat messages for one node: caption prompt plus its images (context crop first)."""
        content: list[dict] = [{"type": "text", "text": CAPTION_PROMPT}]
        for img in req.observations.images():
            content.append({"type": "image_url", "image_url": {"url": image_data_url(img)}})
        return [{"role": "system", "content": CAPTION_SYSTEM_PROMPT}, {"role": "user", "content": content}]

    def _caption_one(self, req: CaptionRequest, breaker: _CircuitBreaker) -> tuple[str, bool] | None:
        """``(caption, is_json)`` for one node, or None (failed, malformed, or skipped by ``breaker``)."""
        if not breaker.allow():
            return None
        try:
            reply = self.client.chat(self.caption_messages(req), max_tokens=self.max_tokens)
        except Exception as e:
            breaker.record(isinstance(e, (EndpointUnreachable, EndpointUnavailable)))
            log.warning(
                "captioner: node %d: request failed (%s); it keeps its previous (or a heuristic) caption "
                "until a later update",
                req.node.id,
                e,
            )
            return None
        breaker.record(False)
        caption, is_json = read_caption_reply(reply)
        if caption is None:
            log.warning("captioner: node %d: malformed caption reply ignored", req.node.id)
            return None
        if not is_json:
            self._warn_prose(req.node.id, reply)
        return caption, is_json

    def _warn_prose(self, node_id: int, reply: str) -> None:
        with self._lock:
            first, self._warned_prose = not self._warned_prose, True
        if first:
            log.warning(
                "captioner: %s answers in prose, not the JSON the caption prompt asks for (node %d: %r); "
                'such replies are kept as captions with caption_source "vlm-text": check that they '
                "describe the objects (a refusal is kept too)",
                self.client.base_url,
                node_id,
                reply[:120],
            )

    def describe(self, requests: Sequence[CaptionRequest]) -> dict[int, Description]:
        todo = [r for r in requests if r.observations.images()]
        if len(todo) < len(requests):
            log.info("captioner: %d node(s) have no observations yet", len(requests) - len(todo))
        if not todo:
            return {}
        breaker = _CircuitBreaker(self.max_consecutive_failures)
        if self.concurrency > 1 and len(todo) > 1:
            with ThreadPoolExecutor(max_workers=min(self.concurrency, len(todo))) as pool:
                captions = list(pool.map(lambda r: self._caption_one(r, breaker), todo))
        else:
            captions = [self._caption_one(r, breaker) for r in todo]
        if breaker.skipped:
            log.warning(
                "captioner: %d requests in a row were not served by %s (connection failed, timed out or "
                "server errors); "
                "skipped the other %d caption request(s) of this update: those nodes keep their previous "
                "(or a heuristic) caption and are asked for again at the next update",
                breaker.limit,
                self.client.base_url,
                breaker.skipped,
            )
        got = {r.node.id: c for r, c in zip(todo, captions) if c is not None}
        if not got:
            return {}
        # the tag request would only wait out the same dead endpoint: derive the tags from the captions
        tags = {} if breaker.tripped else self.tags({i: c for i, (c, _) in got.items()})
        return {
            i: Description(c, tags.get(i) or tag_from_caption(c), "vlm" if is_json else "vlm-text")
            for i, (c, is_json) in got.items()
        }

    def tags(self, captions: Mapping[int, str]) -> dict[int, str]:
        """Tags for all ``{id: caption}`` in ONE request; missing ones are absent from the result."""
        listing = "\n".join(f"{i}: {c}" for i, c in sorted(captions.items()))
        try:
            reply = self.tag_client.chat(
                [{"role": "user", "content": f"{TAG_PROMPT}\n\n{listing}"}],
                max_tokens=max(200, 20 * len(captions)),
            )
        except Exception as e:
            log.warning("captioner: tag request failed (%s); deriving tags from captions", e)
            return {}
        return parse_tag_reply(reply, list(captions))


class HeuristicCaptioner:
    """Offline captions from geometry and colour only, marked "(geometric heuristic)".

    * floor / ceiling: a horizontal sheet (normal within ~25 degrees of up) at least 1 m across, whose
      height lies in the bottom / top ``structure_band`` of the scene's height range;
    * wall: a vertical sheet at least ``wall_min_height`` high and 1 m wide;
    * otherwise "<size> <colour> [flat horizontal | flat vertical] object, about <largest extent>" with
      size small (< 0.3 m), medium (< 1 m) or large.

    Where a detector named the node's segments, its majority class is the tag, unless that class named less
    than ``min_share`` of the node's pixels in the keyframes seen: an object's segments that the mapping gave
    to the surface behind it do not make the surface that object (on a synthetic apartment such names
    covered 0-3 % of a wall, a right name 10 % and more of its node).
    """

    def __init__(
        self, structure_band: float = 0.2, wall_min_height: float = 1.2, min_share: float = 0.1
    ) -> None:
        self.structure_band = structure_band
        self.wall_min_height = wall_min_height
        self.min_share = min_share

    def describe(self, requests: Sequence[CaptionRequest]) -> dict[int, Description]:
        return {r.node.id: self.describe_one(r) for r in requests}

    def describe_one(self, req: CaptionRequest) -> Description:
        """The geometric caption; where a detector named the node's segments, its majority class is the
        tag and leads the caption (source "detector")."""
        desc = self._geometric(req)
        if not req.detector_name_votes:
            return desc
        name, pixels = max(req.detector_name_votes.items(), key=lambda kv: (kv[1], kv[0]))
        if pixels < self.min_share * req.label_pixels:
            share = pixels / req.label_pixels
            return Description(f"{desc.caption}; {share:.0%} of it detected as {name}", desc.tag, desc.source)
        return Description(f"{name} (detector class); {desc.caption}", name, "detector")

    def _geometric(self, req: CaptionRequest) -> Description:
        node, ctx = req.node, req.context
        s = node.shape(ctx.up)
        colour = color_name(node.color)
        size = s.size
        span = max(ctx.h_hi - ctx.h_lo, 1e-6)
        mid = 0.5 * (s.h_lo + s.h_hi)
        across = s.extent[1] >= 1.0
        band = self.structure_band * span
        if s.is_horizontal_plane and across and mid <= ctx.h_lo + band:
            return Description(
                f"{colour} floor, about {format_length(size)} across (geometric heuristic)",
                "floor",
                "heuristic",
            )
        if s.is_horizontal_plane and across and mid >= ctx.h_hi - band:
            return Description(
                f"{colour} ceiling, about {format_length(size)} across (geometric heuristic)",
                "ceiling",
                "heuristic",
            )
        if s.is_vertical_plane and s.height >= self.wall_min_height and s.extent[0] >= 1.0:
            return Description(
                f"{colour} wall, about {format_length(s.height)} high and {format_length(size)} wide "
                "(geometric heuristic)",
                "wall",
                "heuristic",
            )
        adj = "small" if size < 0.3 else "medium" if size < 1.0 else "large"
        flat = (
            " flat horizontal" if s.is_horizontal_plane else " flat vertical" if s.is_vertical_plane else ""
        )
        caption = f"{adj} {colour}{flat} object, about {format_length(size)} (geometric heuristic)"
        return Description(caption, f"{colour} object", "heuristic")


class GroundTruthCaptioner:
    """Ground-truth names for synthetic scenes (evaluation only: it reads the answer, it does not see).

    ``label_names`` maps scene label -> class name directly. Otherwise the node's majority ground-truth
    class among the pixels it covered in ``SceneGraph.observe`` (``CaptionRequest.gt_class_votes``) is
    named through ``class_names`` (class id -> name; unknown ids are called "class <id>"). Nodes with
    neither are left out.
    """

    def __init__(
        self, label_names: Mapping[int, str] | None = None, class_names: Mapping[int, str] | None = None
    ) -> None:
        self.label_names = {int(k): str(v) for k, v in (label_names or {}).items()}
        self.class_names = {int(k): str(v) for k, v in (class_names or {}).items()}

    def describe(self, requests: Sequence[CaptionRequest]) -> dict[int, Description]:
        out: dict[int, Description] = {}
        for r in requests:
            name = self.label_names.get(r.node.id)
            if name is None and r.gt_class_votes:
                cls, _ = max(r.gt_class_votes.items(), key=lambda kv: (kv[1], -kv[0]))
                name = self.class_names.get(cls, f"class {cls}")
            if name is not None:
                out[r.node.id] = Description(f"{name} (ground truth)", name, "groundtruth")
        return out


def build_captioner(
    config: CaptionerConfig,
    label_names: Mapping[int, str] | None = None,
    class_names: Mapping[int, str] | None = None,
    endpoint: EndpointConfig | None = None,
) -> Captioner:
    """The captioner selected by ``graph.captioner.kind`` (heuristic | openai | groundtruth); ``endpoint``:
    the one ``openai`` calls (``graph.endpoint``; None: the defaults)."""
    if config.kind == "heuristic":
        return HeuristicCaptioner()
    if config.kind == "openai":
        return OpenAICaptioner.from_config(config, endpoint)
    if config.kind == "groundtruth":
        return GroundTruthCaptioner(label_names, class_names)
    raise ConfigError(f"graph.captioner.kind must be heuristic, openai or groundtruth, got {config.kind!r}")
