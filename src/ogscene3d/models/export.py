"""``ogscene3d models export``: ONNX files our loaders read, made from the official releases' checkpoints.

Each kind loads the checkpoint with its official package and exports through that package's own model
classes (extra ``ogscene3d[export]``; nothing is downloaded here, the checkpoint is a local file or
folder the user fetched):

* ``sam-vit-b`` / ``sam-vit-l`` / ``sam-vit-h`` (segment-anything) and ``mobile-sam`` (MobileSAM's
  ``mobile_sam`` package, same interfaces): the prompt decoder through the package's ``SamOnnxModel``
  with the inputs and outputs of its ``scripts/export_onnx_model.py`` (multimask outputs, prompt batch
  and count dynamic), and the image encoder ``[1, 3, S, S]`` (normalised, padded) -> ``image_embeddings``;
* ``open-clip``: ``open_clip.create_model_and_transforms(ARCH, pretrained=CHECKPOINT)``; ``encode_image``
  and ``encode_text`` exported separately; open_clip's own BPE vocabulary file is copied beside them;
* ``hf-clip``: a Hugging Face CLIP folder (``CLIPModel.from_pretrained``); ``get_image_features`` and
  ``get_text_features``; its ``tokenizer.json`` (or ``vocab.json`` + ``merges.txt``) is copied;
* ``yolo-world``: Ultralytics ``YOLOWorld(CHECKPOINT).set_classes(VOCABULARY)`` then its
  ``export(format="onnx")``; ``set_classes`` runs CLIP's text encoder, which Ultralytics downloads on
  first use, so this kind needs that download (or its cache) once, or the classes' CLIP text embeddings
  given as a ``.npy`` (``--text-embeddings``).

Every export writes ``models.json`` (:mod:`.manifest`), read by ``ogscene3d run --models DIR``.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import ConfigError, ModelError
from .manifest import update_manifest

log = logging.getLogger(__name__)

SAM_KINDS = {"sam-vit-b": "vit_b", "sam-vit-l": "vit_l", "sam-vit-h": "vit_h", "mobile-sam": "vit_t"}
KINDS = (*SAM_KINDS, "open-clip", "hf-clip", "yolo-world")
DEFAULT_OPSET = 17


def _need(module: str, package: str, kind: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ModelError(
            f"models export {kind}: the {package} package is missing or does not import ({e}); install it "
            f"(pip install 'ogscene3d[export]' {package})"
        ) from None


def _onnx_export(
    module: Any,
    args: tuple,
    path: Path,
    input_names: list[str],
    output_names: list[str],
    dynamic_axes: dict[str, dict[int, str]],
    opset: int,
) -> Path:
    import torch

    path.parent.mkdir(parents=True, exist_ok=True)
    # nn.MultiheadAttention's inference fast path (open_clip's text and vision towers) is a fused op with
    # no ONNX export: trace the plain ops
    fastpath = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        _trace(module, args, path, input_names, output_names, dynamic_axes, opset)
    finally:
        torch.backends.mha.set_fastpath_enabled(fastpath)
    return path


def _trace(module, args, path, input_names, output_names, dynamic_axes, opset) -> None:
    import torch

    with torch.no_grad():
        # the TorchScript exporter: the dynamo one needs onnxscript and cannot trace segment-anything's
        # data-dependent prompt embedding
        torch.onnx.export(
            module,
            args,
            str(path),
            export_params=True,
            opset_version=int(opset),
            do_constant_folding=True,
            input_names=input_names,
            output_names=output_names,
            dynamic_axes=dynamic_axes,
            dynamo=False,
        )


# ------------------------------------------------------------------------------------------------- SAM


def export_sam_model(sam: Any, onnx_model_cls: type, out: Path, opset: int = DEFAULT_OPSET) -> dict[str, Any]:
    """Export a loaded segment-anything (or MobileSAM) ``Sam``: ``sam_encoder.onnx`` and
    ``sam_decoder.onnx`` in ``out``; returns the manifest entry (without kind/checkpoint)."""
    import torch

    sam = sam.eval()
    size = int(sam.image_encoder.img_size)

    class _Encoder(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.encoder = sam.image_encoder

        def forward(self, image: torch.Tensor) -> torch.Tensor:
            return self.encoder(image)

    _onnx_export(
        _Encoder().eval(),
        (torch.randn(1, 3, size, size),),
        out / "sam_encoder.onnx",
        ["image"],
        ["image_embeddings"],
        {},
        opset,
    )
    # the decoder as segment-anything's scripts/export_onnx_model.py exports it, with the prompt batch
    # dynamic too (automatic mask generation sends points_per_batch prompts at once)
    decoder = onnx_model_cls(model=sam, return_single_mask=False).eval()
    embed_dim = sam.prompt_encoder.embed_dim
    embed_size = sam.prompt_encoder.image_embedding_size
    dummy = {
        "image_embeddings": torch.randn(1, embed_dim, *embed_size, dtype=torch.float),
        "point_coords": torch.randint(low=0, high=size, size=(1, 5, 2), dtype=torch.float),
        "point_labels": torch.randint(low=0, high=4, size=(1, 5), dtype=torch.float),
        "mask_input": torch.randn(1, 1, *[4 * x for x in embed_size], dtype=torch.float),
        "has_mask_input": torch.tensor([1], dtype=torch.float),
        "orig_im_size": torch.tensor([1500, 2250], dtype=torch.float),
    }
    prompts = {0: "batch", 1: "num_points"}
    _onnx_export(
        decoder,
        tuple(dummy.values()),
        out / "sam_decoder.onnx",
        list(dummy),
        ["masks", "iou_predictions", "low_res_masks"],
        {"point_coords": prompts, "point_labels": prompts},
        opset,
    )
    return {"encoder": "sam_encoder.onnx", "decoder": "sam_decoder.onnx", "input_size": size}


def _export_sam(kind: str, checkpoint: Path, out: Path, opset: int) -> dict[str, Any]:
    if kind == "mobile-sam":
        pkg = _need("mobile_sam", "mobile_sam (MobileSAM, github.com/ChaoningZhang/MobileSAM)", kind)
        onnx_mod = _need("mobile_sam.utils.onnx", "mobile_sam", kind)
    else:
        pkg = _need("segment_anything", "segment-anything", kind)
        onnx_mod = _need("segment_anything.utils.onnx", "segment-anything", kind)
    try:
        sam = pkg.sam_model_registry[SAM_KINDS[kind]](checkpoint=str(checkpoint))
    except Exception as e:  # torch.load / state-dict mismatches raise many types
        raise ModelError(
            f"{checkpoint}: cannot load as a {kind} checkpoint ({type(e).__name__}: {e})"
        ) from None
    return export_sam_model(sam, onnx_mod.SamOnnxModel, out, opset)


# ------------------------------------------------------------------------------------------------ CLIP


def export_clip_encoders(
    owner: Any,
    encode_image: Callable,
    encode_text: Callable,
    image_size: int,
    context_length: int,
    out: Path,
    opset: int = DEFAULT_OPSET,
    with_attention_mask: bool = False,
) -> dict[str, Any]:
    """``clip_image.onnx`` (``pixel_values [N, 3, S, S]`` -> ``image_embeds``) and ``clip_text.onnx``
    (``input_ids [N, L]`` (+ ``attention_mask``) -> ``text_embeds``) from a model's two encoders.
    ``owner``: the torch module the encoders belong to (held by the exported wrappers, so that its
    weights are exported as parameters)."""
    import torch

    class _Image(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.owner = owner

        def forward(self, pixel_values: torch.Tensor) -> torch.Tensor:
            return encode_image(pixel_values)

    class _Text(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.owner = owner

        def forward(
            self, input_ids: torch.Tensor, attention_mask: torch.Tensor | None = None
        ) -> torch.Tensor:
            return encode_text(input_ids, attention_mask) if with_attention_mask else encode_text(input_ids)

    batch = {0: "batch"}
    _onnx_export(
        _Image().eval(),
        (torch.randn(2, 3, image_size, image_size),),
        out / "clip_image.onnx",
        ["pixel_values"],
        ["image_embeds"],
        {"pixel_values": batch, "image_embeds": batch},
        opset,
    )
    ids = torch.zeros(2, context_length, dtype=torch.int64)
    ids[:, 0], ids[:, 1], ids[:, 2] = 1, 2, 3  # any ids: the graph does not depend on their values
    names = ["input_ids"] + (["attention_mask"] if with_attention_mask else [])
    args = (ids, torch.ones_like(ids)) if with_attention_mask else (ids,)
    _onnx_export(
        _Text().eval(),
        args,
        out / "clip_text.onnx",
        names,
        ["text_embeds"],
        {**{n: batch for n in names}, "text_embeds": batch},
        opset,
    )
    return {
        "image": "clip_image.onnx",
        "text": "clip_text.onnx",
        "image_size": int(image_size),
        "context_length": int(context_length),
    }


def _image_size(value: Any) -> int:
    size = value if isinstance(value, int) else value[0]
    return int(size)


def export_open_clip_model(model: Any, out: Path, opset: int = DEFAULT_OPSET) -> dict[str, Any]:
    """Export a loaded open_clip ``CLIP`` model and copy open_clip's BPE vocabulary beside it."""
    import open_clip

    entry = export_clip_encoders(
        model,
        model.encode_image,
        model.encode_text,
        _image_size(model.visual.image_size),
        int(model.context_length),
        out,
        opset,
    )
    vocab = Path(open_clip.__file__).parent / "bpe_simple_vocab_16e6.txt.gz"
    if not vocab.is_file():
        raise ModelError(f"open_clip's BPE vocabulary {vocab} is missing from the installed package")
    shutil.copyfile(vocab, out / vocab.name)
    return {**entry, "vocab": vocab.name, "merges": None}


def _export_open_clip(checkpoint: Path, arch: str | None, out: Path, opset: int) -> dict[str, Any]:
    open_clip = _need("open_clip", "open-clip-torch", "open-clip")
    if not arch:
        raise ConfigError("models export open-clip needs --arch (an open_clip model name, e.g. ViT-B-32)")
    try:
        model, _, _ = open_clip.create_model_and_transforms(arch, pretrained=str(checkpoint))
    except Exception as e:
        raise ModelError(f"{checkpoint}: cannot load as open_clip {arch} ({type(e).__name__}: {e})") from None
    return export_open_clip_model(model.eval(), out, opset)


def _features(output: Any) -> Any:
    """transformers 4 returns the projected features as a tensor, 5 as the output's pooler_output."""
    import torch

    return output if torch.is_tensor(output) else output.pooler_output


def export_hf_clip_model(
    model: Any, out: Path, tokenizer_dir: Path | None, opset: int = DEFAULT_OPSET
) -> dict:
    """Export a loaded Hugging Face ``CLIPModel``; copy the tokenizer files found in ``tokenizer_dir``."""
    cfg = model.config
    entry = export_clip_encoders(
        model,
        lambda x: _features(model.get_image_features(pixel_values=x)),
        lambda ids, mask: _features(model.get_text_features(input_ids=ids, attention_mask=mask)),
        int(cfg.vision_config.image_size),
        int(cfg.text_config.max_position_embeddings),
        out,
        opset,
        with_attention_mask=True,
    )
    src = Path(tokenizer_dir) if tokenizer_dir else None
    if src is not None and (src / "tokenizer.json").is_file():
        shutil.copyfile(src / "tokenizer.json", out / "tokenizer.json")
        return {**entry, "vocab": "tokenizer.json", "merges": None}
    if src is not None and (src / "vocab.json").is_file() and (src / "merges.txt").is_file():
        for name in ("vocab.json", "merges.txt"):
            shutil.copyfile(src / name, out / name)
        return {**entry, "vocab": "vocab.json", "merges": "merges.txt"}
    raise ModelError(
        f"{tokenizer_dir}: no tokenizer.json, nor vocab.json + merges.txt, beside the CLIP checkpoint "
        "(a Hugging Face CLIP folder has them)"
    )


def _export_hf_clip(checkpoint: Path, out: Path, opset: int) -> dict[str, Any]:
    transformers = _need("transformers", "transformers", "hf-clip")
    if not checkpoint.is_dir():
        raise ConfigError(
            f"models export hf-clip: --checkpoint must be a Hugging Face CLIP folder, got {checkpoint}"
        )
    try:
        model = transformers.CLIPModel.from_pretrained(str(checkpoint), local_files_only=True)
    except Exception as e:
        raise ModelError(
            f"{checkpoint}: cannot load as a Hugging Face CLIPModel ({type(e).__name__}: {e})"
        ) from None
    return export_hf_clip_model(model.eval(), out, checkpoint, opset)


# ------------------------------------------------------------------------------------------ YOLO-World


def set_world_classes(model: Any, classes: Sequence[str], text_embeddings: Any | None = None) -> None:
    """Give an Ultralytics ``YOLOWorld`` its vocabulary: ``set_classes`` (CLIP's text encoder, which
    Ultralytics downloads on first use), or, offline, the classes' CLIP text embeddings ``[K, D]``
    computed elsewhere (normalised here, as ``set_classes`` does)."""
    if text_embeddings is None:
        model.set_classes(list(classes))
        return
    import numpy as np
    import torch

    emb = np.asarray(text_embeddings, dtype=np.float32)
    world = model.model
    dim = int(world.txt_feats.shape[-1])
    if emb.shape != (len(classes), dim) or not np.all(np.isfinite(emb)):
        raise ConfigError(
            f"YOLO-World text embeddings must be finite [{len(classes)} classes, {dim}], got {emb.shape}"
        )
    world.txt_feats = torch.nn.functional.normalize(torch.from_numpy(emb)[None], dim=-1)
    world.model[-1].nc = len(classes)
    world.names = list(classes)


def export_yolo_world_model(
    model: Any, classes: Sequence[str], out: Path, image_size: int = 640, opset: int = DEFAULT_OPSET
) -> dict[str, Any]:
    """Ultralytics' own ONNX export of a ``YOLOWorld`` whose classes are set; ``detector.onnx`` in ``out``."""
    produced = Path(model.export(format="onnx", imgsz=int(image_size), opset=int(opset)))
    out.mkdir(parents=True, exist_ok=True)
    shutil.move(str(produced), out / "detector.onnx")
    return {"model": "detector.onnx", "classes": list(classes), "input_size": int(image_size)}


def _export_yolo_world(
    checkpoint: Path,
    classes: Sequence[str],
    out: Path,
    image_size: int | None,
    opset: int,
    text_embeddings: str | Path | None,
) -> dict[str, Any]:
    ultralytics = _need("ultralytics", "ultralytics", "yolo-world")
    if not classes:
        raise ConfigError("models export yolo-world needs --classes (the vocabulary, e.g. chair,table,lamp)")
    emb = None
    if text_embeddings is not None:
        import numpy as np

        try:
            emb = np.load(text_embeddings)
        except (OSError, ValueError) as e:
            raise ConfigError(f"{text_embeddings}: cannot read the text embeddings (.npy): {e}") from None
    try:
        model = ultralytics.YOLOWorld(str(checkpoint))
        set_world_classes(model, classes, emb)
        return export_yolo_world_model(model, classes, out, int(image_size or 640), opset)
    except ConfigError:
        raise
    except Exception as e:
        hint = (
            ""
            if emb is not None
            else (
                "; set_classes needs CLIP's text encoder, which Ultralytics downloads on first use (offline: "
                "pass --text-embeddings)"
            )
        )
        raise ModelError(f"{checkpoint}: YOLO-World export failed ({type(e).__name__}: {e}){hint}") from None


# ---------------------------------------------------------------------------------------------- front


def export_models(
    kind: str,
    checkpoint: str | Path,
    out: str | Path,
    *,
    arch: str | None = None,
    classes: Sequence[str] | None = None,
    image_size: int | None = None,
    opset: int = DEFAULT_OPSET,
    text_embeddings: str | Path | None = None,
) -> Path:
    """Export ``kind`` from ``checkpoint`` into ``out`` and record it in ``out/models.json``; returns the
    manifest's path. ``arch``: the open_clip model name; ``classes``: YOLO-World's vocabulary;
    ``image_size``: YOLO-World's input size (640); ``text_embeddings``: a ``.npy`` of the classes' CLIP
    text embeddings for YOLO-World instead of ``set_classes`` (which downloads CLIP)."""
    if kind not in KINDS:
        raise ConfigError(f"models export: unknown kind {kind!r}; expected one of {list(KINDS)}")
    ckpt = Path(checkpoint)
    if not ckpt.exists():
        raise ConfigError(f"models export {kind}: checkpoint {ckpt} does not exist")
    dest = Path(out)
    dest.mkdir(parents=True, exist_ok=True)
    if kind in SAM_KINDS:
        section, entry = "sam", _export_sam(kind, ckpt, dest, opset)
    elif kind == "open-clip":
        section, entry = "clip", _export_open_clip(ckpt, arch, dest, opset)
    elif kind == "hf-clip":
        section, entry = "clip", _export_hf_clip(ckpt, dest, opset)
    else:
        section, entry = (
            "detector",
            _export_yolo_world(ckpt, classes or [], dest, image_size, opset, text_embeddings),
        )
    entry = {"kind": kind, "checkpoint": str(ckpt.resolve()), **({"arch": arch} if arch else {}), **entry}
    path = update_manifest(dest, section, entry)
    log.info(
        "models export %s: wrote %s",
        kind,
        ", ".join(str(dest / v) for k, v in entry.items() if isinstance(v, str) and v.endswith(".onnx")),
    )
    return path
