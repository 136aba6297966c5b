"""Node confidence C_i (paper Eq. 19) behind the :class:`NodeConfidence` protocol.

* :class:`ClipConfidence`: CLIP image-text cosine similarity between the node's context crop c_i and its
  caption, with user-supplied ONNX CLIP image and text encoders run by onnxruntime. The value is the
  raw cosine clipped to [0, 1] (as the paper's tau_update = 0.3 assumes: matching CLIP pairs score about
  0.25-0.35). Nodes without any crop get the fallback value.
* :class:`MeanConfidence` (the documented fallback): the mean confidence of the node's Gaussians. It does
  not judge the caption, so with it C_i < tau_update means "the map itself is unsure about this region".

Model expectations (ONNX, exported e.g. from ``openai/clip-vit-base-patch32`` with optimum or
``torch.onnx.export``):

* image model: one float32 input ``[N, 3, S, S]`` (S read from the model; when dynamic,
  ``graph.confidence.clip_image_size``, else 224), CLIP
  preprocessing (shorter side resized to S, centre crop, mean/std normalisation) is done here;
  output: the projected image embedding ``[N, D]`` (an output whose name contains "embed" is preferred).
* text model: an integer token-id input ``[N, L]`` (L read from the model, 77 when dynamic) and
  optionally an ``attention_mask``; output: the projected text embedding ``[N, D]``.
* tokenizer: CLIP's byte-level BPE on Hugging Face ``tokenizers`` (:class:`ClipTokenizer`, extra
  ``clip``), loaded from the user's vocabulary file: OpenAI's ``bpe_simple_vocab_16e6.txt(.gz)``
  (``graph.confidence.clip_vocab``), a Hugging Face ``tokenizer.json``, or a Hugging Face ``vocab.json``
  with its ``merges.txt`` (``graph.confidence.clip_merges``). Sequences are
  ``<|startoftext|> tokens <|endoftext|>`` padded with 0 (models pool at the end-of-text token, the
  largest id, via argmax, so the padding id does not matter).
"""

from __future__ import annotations

import gzip
import html
import json
import logging
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from .._validate import check_int
from ..config import NodeConfidenceConfig
from ..errors import ConfigError, ModelError
from .types import CaptionRequest

log = logging.getLogger(__name__)

CLIP_MEAN = np.array([0.48145466, 0.4578275, 0.40821073], dtype=np.float32)
CLIP_STD = np.array([0.26862954, 0.26130258, 0.27577711], dtype=np.float32)


@runtime_checkable
class NodeConfidence(Protocol):
    """Scores captioned nodes: ``{node id: C_i in [0, 1]}`` for every request (captions already set)."""

    def score(self, requests: Sequence[CaptionRequest]) -> dict[int, float]: ...


class MeanConfidence:
    """C_i = mean confidence of the node's Gaussians (fallback when no CLIP models are configured)."""

    def score(self, requests: Sequence[CaptionRequest]) -> dict[int, float]:
        return {r.node.id: float(np.clip(r.node.mean_confidence, 0.0, 1.0)) for r in requests}


# --------------------------------------------------------------------------------------------------
# CLIP byte-level BPE tokenizer on Hugging Face ``tokenizers`` (the normaliser, pre-tokeniser and BPE model
# of CLIP's fast tokenizer), read from the user's vocabulary files.


@lru_cache
def _bytes_to_unicode() -> dict[int, str]:
    """CLIP's (GPT-2's) byte -> printable character table: the base of the vocabulary derived from
    OpenAI's merges-only ``bpe_simple_vocab_16e6.txt``."""
    bs = (
        list(range(ord("!"), ord("~") + 1))
        + list(range(ord("¡"), ord("¬") + 1))
        + list(range(ord("®"), ord("ÿ") + 1))
    )
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, [chr(c) for c in cs]))


# CLIP's word pattern (simple_tokenizer.py), as Hugging Face's CLIP converter writes it
_CLIP_SPLIT = (
    r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""
)


def _tokenizers():
    try:
        import tokenizers
    except ImportError:
        raise ModelError(
            "the CLIP tokenizer needs the tokenizers package: pip install tokenizers "
            "(or pip install 'ogscene3d[clip]')"
        ) from None
    return tokenizers


class ClipTokenizer:
    """CLIP BPE tokenizer (Hugging Face ``tokenizers``). Build with :meth:`from_files`."""

    def __init__(self, encoder: dict[str, int], merges: list[tuple[str, str]], tokenizer=None) -> None:
        """``tokenizer``: a ready ``tokenizers.Tokenizer`` (a ``tokenizer.json``); otherwise CLIP's is
        built from ``encoder`` (token -> id) and ``merges``."""
        self.encoder = encoder
        try:
            self.sot = encoder["<|startoftext|>"]
            self.eot = encoder["<|endoftext|>"]
        except KeyError:
            raise ModelError("CLIP vocabulary lacks <|startoftext|> / <|endoftext|>") from None
        if tokenizer is None:
            tk = _tokenizers()
            from tokenizers import normalizers, pre_tokenizers
            from tokenizers.models import BPE

            tokenizer = tk.Tokenizer(
                BPE(vocab=dict(encoder), merges=list(merges), end_of_word_suffix="</w>", fuse_unk=False)
            )
            tokenizer.normalizer = normalizers.Sequence(
                [normalizers.NFC(), normalizers.Replace(tk.Regex(r"\s+"), " "), normalizers.Lowercase()]
            )
            tokenizer.pre_tokenizer = pre_tokenizers.Sequence(
                [
                    pre_tokenizers.Split(tk.Regex(_CLIP_SPLIT), behavior="removed", invert=True),
                    pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
                ]
            )
        self.tokenizer = tokenizer

    @classmethod
    def from_files(cls, vocab: str | Path, merges: str | Path | None = None) -> ClipTokenizer:
        """OpenAI ``bpe_simple_vocab_16e6.txt[.gz]`` (merges only; the vocabulary is derived from it), a
        Hugging Face ``tokenizer.json``, or a Hugging Face ``vocab.json`` plus ``merges.txt``
        (``merges`` argument, or next to vocab.json)."""
        vocab = Path(vocab)
        if not vocab.is_file():
            raise ModelError(f"CLIP vocabulary file {str(vocab)!r} does not exist")
        if vocab.name.endswith("tokenizer.json"):
            tk = _tokenizers()
            try:
                tokenizer = tk.Tokenizer.from_file(str(vocab))
            except Exception as e:
                raise ModelError(f"cannot read CLIP tokenizer {str(vocab)!r}: {e}") from None
            return cls(tokenizer.get_vocab(), [], tokenizer)
        if vocab.suffix == ".json":
            mpath = Path(merges) if merges else vocab.with_name("merges.txt")
            if not mpath.is_file():
                raise ModelError(f"CLIP merges file {str(mpath)!r} (needed with {vocab.name}) does not exist")
            try:
                encoder = json.loads(vocab.read_text(encoding="utf-8"))
            except (json.JSONDecodeError, UnicodeDecodeError) as e:
                raise ModelError(f"CLIP vocabulary {str(vocab)!r} is not valid JSON: {e}") from None
            lines = _read_lines(mpath)
            merge_list = [tuple(ln.split()) for ln in lines if ln and not ln.startswith("#version")]
            return cls({str(k): int(v) for k, v in encoder.items()}, _check_merges(merge_list, mpath))
        lines = _read_lines(vocab)
        # OpenAI's file: a version line, then the merges CLIP uses (49152 - 256 - 2 of them).
        merge_list = [tuple(ln.split()) for ln in lines[1 : 49152 - 256 - 2 + 1] if ln]
        merge_list = _check_merges(merge_list, vocab)
        base = list(_bytes_to_unicode().values())
        words = base + [v + "</w>" for v in base] + ["".join(m) for m in merge_list]
        words += ["<|startoftext|>", "<|endoftext|>"]
        return cls({w: i for i, w in enumerate(words)}, merge_list)

    def encode(self, text: str) -> list[int]:
        """Token ids of ``text`` without start/end tokens (CLIP's HTML unescaping first)."""
        text = html.unescape(html.unescape(text)).strip()
        return list(self.tokenizer.encode(text, add_special_tokens=False).ids)

    def __call__(self, texts: Sequence[str], context_length: int = 77) -> np.ndarray:
        """int64 [len(texts), context_length]: start, tokens (truncated), end, zero padding."""
        out = np.zeros((len(texts), context_length), dtype=np.int64)
        for k, t in enumerate(texts):
            ids = [self.sot] + self.encode(t)[: context_length - 2] + [self.eot]
            out[k, : len(ids)] = ids
        return out


def _read_lines(path: Path) -> list[str]:
    try:
        raw = gzip.open(path).read() if path.suffix == ".gz" else path.read_bytes()
        return raw.decode("utf-8").split("\n")
    except (OSError, UnicodeDecodeError) as e:
        raise ModelError(f"cannot read CLIP tokenizer file {str(path)!r}: {e}") from None


def _check_merges(merges: list[tuple], path: Path) -> list[tuple[str, str]]:
    bad = [m for m in merges if len(m) != 2]
    if bad or not merges:
        raise ModelError(f"CLIP merges in {str(path)!r} are malformed (expected 'a b' per line)")
    return [(m[0], m[1]) for m in merges]


# --------------------------------------------------------------------------------------------------


def _providers(execution_provider: str) -> list[str]:
    import onnxruntime as ort

    avail = ort.get_available_providers()
    if execution_provider == "cpu":
        return ["CPUExecutionProvider"]
    if execution_provider == "cuda":
        if "CUDAExecutionProvider" not in avail:
            raise ModelError("graph.confidence.execution_provider=cuda but onnxruntime has no CUDA provider")
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    if execution_provider == "auto":
        return [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in avail]
    raise ConfigError(
        f"graph.confidence.execution_provider must be auto, cpu or cuda, got {execution_provider!r}"
    )


def _session(path: str, providers: list[str], what: str):
    import onnxruntime as ort

    p = Path(path)
    if not p.is_file():
        raise ModelError(f"CLIP {what} model {str(p)!r} does not exist")
    try:
        return ort.InferenceSession(str(p), providers=providers)
    except Exception as e:
        raise ModelError(f"CLIP {what} model {str(p)!r} could not be loaded by onnxruntime: {e}") from None


def _embedding_output(sess, what: str) -> str:
    outs = sess.get_outputs()
    named = [o for o in outs if "embed" in o.name.lower()]
    return (named or outs)[0].name


def _static_dim(shape: list, idx: int, default: int) -> int:
    try:
        v = shape[idx]
    except IndexError:
        return default
    return v if isinstance(v, int) and v > 0 else default


def clip_preprocess(rgb: np.ndarray, size: int) -> np.ndarray:
    """CLIP preprocessing of a uint8 RGB image -> float32 [3, size, size] (resize shorter side, centre crop,
    normalise with CLIP's mean/std)."""
    import cv2

    h, w = rgb.shape[:2]
    s = size / min(h, w)
    nh, nw = max(size, round(h * s)), max(size, round(w * s))
    img = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_CUBIC)
    y0, x0 = (nh - size) // 2, (nw - size) // 2
    img = img[y0 : y0 + size, x0 : x0 + size].astype(np.float32) / 255.0
    return ((img - CLIP_MEAN) / CLIP_STD).transpose(2, 0, 1)


class ClipConfidence:
    """C_i = clip(cos(CLIP_image(c_i), CLIP_text(caption_i)), 0, 1) with ONNX CLIP encoders.

    The image is the node's context crop (paper Eq. 19), else its largest masked view; nodes with no crop
    or no caption get the ``fallback`` score (mean Gaussian confidence by default).
    """

    def __init__(
        self,
        image_model: str,
        text_model: str,
        tokenizer: ClipTokenizer,
        execution_provider: str = "auto",
        fallback: NodeConfidence | None = None,
        image_size: int | None = None,
    ) -> None:
        providers = _providers(execution_provider)
        self.image_sess = _session(image_model, providers, "image")
        self.text_sess = _session(text_model, providers, "text")
        self.tokenizer = tokenizer
        self.fallback = fallback or MeanConfidence()
        img_in = self.image_sess.get_inputs()
        if len(img_in) != 1 or "float" not in img_in[0].type:
            raise ModelError(f"CLIP image model {image_model!r}: expected one float input [N,3,S,S]")
        self._img_input = img_in[0].name
        static = _static_dim(img_in[0].shape, 2, 0)
        if image_size is not None:
            image_size = check_int("graph.confidence.clip_image_size", image_size, 1)
        if static and image_size is not None and image_size != static:
            raise ModelError(
                f"CLIP image model {image_model!r} takes {static}x{static} images, but "
                f"graph.confidence.clip_image_size is {image_size}: drop the setting or export another size"
            )
        # a dynamic export does not say which size it was trained at: 224 (ViT-B/32, B/16, L/14) unless told
        self.image_size = static or image_size or 224
        self._img_output = _embedding_output(self.image_sess, "image")
        txt_in = self.text_sess.get_inputs()
        ids = [i for i in txt_in if "mask" not in i.name.lower()]
        if len(ids) != 1 or "int" not in ids[0].type:
            raise ModelError(
                f"CLIP text model {text_model!r}: expected one integer token-id input (and optionally an "
                f"attention_mask), got {[(i.name, i.type) for i in txt_in]}"
            )
        self._ids_input = ids[0]
        self._mask_inputs = [i for i in txt_in if "mask" in i.name.lower()]
        self.context_length = _static_dim(ids[0].shape, 1, 77)
        self._txt_output = _embedding_output(self.text_sess, "text")

    @classmethod
    def from_config(cls, config: NodeConfidenceConfig) -> ClipConfidence:
        missing = [k for k in ("clip_image", "clip_text", "clip_vocab") if not getattr(config, k)]
        if missing:
            raise ConfigError(
                f"graph.confidence.kind=clip needs {', '.join('graph.confidence.' + m for m in missing)}"
            )
        tok = ClipTokenizer.from_files(config.clip_vocab, config.clip_merges)  # type: ignore[arg-type]
        return cls(
            config.clip_image,  # type: ignore[arg-type]
            config.clip_text,  # type: ignore[arg-type]
            tok,
            config.execution_provider,
            image_size=config.clip_image_size,
        )

    def _run(self, sess, feeds: dict, output: str, what: str) -> np.ndarray:
        out = np.asarray(sess.run([output], feeds)[0], dtype=np.float32)
        if out.ndim != 2:
            raise ModelError(
                f"CLIP {what} model output {output!r} has shape {out.shape}; expected [N, D] embeddings"
            )
        norm = np.linalg.norm(out, axis=1, keepdims=True)
        return out / np.maximum(norm, 1e-12)

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """L2-normalised image embeddings [N, D] for uint8 RGB images."""
        batch = np.stack([clip_preprocess(im, self.image_size) for im in images]).astype(np.float32)
        if _static_dim(self.image_sess.get_inputs()[0].shape, 0, -1) == 1:
            return np.concatenate(
                [
                    self._run(self.image_sess, {self._img_input: b[None]}, self._img_output, "image")
                    for b in batch
                ]
            )
        return self._run(self.image_sess, {self._img_input: batch}, self._img_output, "image")

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        """L2-normalised text embeddings [N, D]."""
        ids = self.tokenizer(list(texts), self.context_length)
        dtype = np.int32 if "int32" in self._ids_input.type else np.int64

        def feeds(sel: np.ndarray) -> dict:
            f = {self._ids_input.name: sel.astype(dtype)}
            for m in self._mask_inputs:
                eot_pos = np.argmax(sel == self.tokenizer.eot, axis=1)
                mask = (np.arange(sel.shape[1])[None] <= eot_pos[:, None]).astype(
                    np.int32 if "int32" in m.type else np.float32 if "float" in m.type else np.int64
                )
                f[m.name] = mask
            return f

        if _static_dim(self._ids_input.shape, 0, -1) == 1:
            return np.concatenate(
                [self._run(self.text_sess, feeds(i[None]), self._txt_output, "text") for i in ids]
            )
        return self._run(self.text_sess, feeds(ids), self._txt_output, "text")

    def score(self, requests: Sequence[CaptionRequest]) -> dict[int, float]:
        out = self.fallback.score(requests)
        usable = []
        for r in requests:
            img = r.observations.context or (r.observations.masked[0] if r.observations.masked else None)
            if img is not None and r.node.caption:
                usable.append((r.node.id, img.image, r.node.caption))
        if not usable:
            return out
        ie = self.embed_images([u[1] for u in usable])
        te = self.embed_texts([u[2] for u in usable])
        if ie.shape[1] != te.shape[1]:
            raise ModelError(
                f"CLIP image and text embeddings differ in size ({ie.shape[1]} vs {te.shape[1]})"
            )
        sims = np.sum(ie * te, axis=1)
        for (i, _, _), s in zip(usable, sims):
            out[i] = float(np.clip(s, 0.0, 1.0))
        return out


def build_confidence(config: NodeConfidenceConfig) -> NodeConfidence:
    """The node-confidence scorer selected by ``graph.confidence.kind`` (mean | clip)."""
    if config.kind == "mean":
        return MeanConfidence()
    if config.kind == "clip":
        return ClipConfidence.from_config(config)
    raise ConfigError(f"graph.confidence.kind must be 'mean' or 'clip', got {config.kind!r}")
