"""``ogscene3d models export`` end to end: small, randomly initialised models built from the official
packages' own classes, exported, then read back by our loaders (SamOnnx, ClipConfidence); and the manifest
that ``run --models`` applies. Each export test skips when its package is not installed (segment-anything
and open_clip need torchvision, which does not import beside the CPU torch of the main environment)."""

import json
import os

import numpy as np
import pytest

from ogscene3d import cli
from ogscene3d.config import load_config
from ogscene3d.errors import ConfigError
from ogscene3d.models.manifest import MANIFEST, manifest_overrides, update_manifest

MERGES = ["g r", "gr e", "gre e", "gree n</w>", "r e", "re d</w>", "b l", "bl u", "blu e</w>", "c h", "ch a"]


def _touch(d, *names):
    for n in names:
        (d / n).write_bytes(b"x")


def test_manifest_sets_the_run_config_and_names_what_is_wrong(tmp_path):
    d = tmp_path / "models"
    d.mkdir()
    _touch(d, "sam_encoder.onnx", "sam_decoder.onnx", "detector.onnx", "clip_image.onnx", "clip_text.onnx")
    _touch(d, "vocab.json", "merges.txt")
    sam = {"kind": "sam-vit-b", "encoder": "sam_encoder.onnx", "decoder": "sam_decoder.onnx"}
    update_manifest(d, "sam", sam)
    over = manifest_overrides(d)
    cfg = load_config(None, over)
    assert cfg.segmentation.backend == "sam"
    assert cfg.segmentation.sam_encoder == str((d / "sam_encoder.onnx").resolve())
    update_manifest(d, "detector", {"kind": "yolo-world", "model": "detector.onnx",
                                    "classes": ["chair", "coffee table"], "input_size": 480})  # fmt: skip
    update_manifest(d, "clip", {"kind": "hf-clip", "image": "clip_image.onnx", "text": "clip_text.onnx",
                                "vocab": "vocab.json", "merges": "merges.txt", "image_size": 32})  # fmt: skip
    cfg = load_config(None, manifest_overrides(d) + ["segmentation.detector_input_size=320"])
    s, c = cfg.segmentation, cfg.graph.confidence
    assert s.backend == "sam+detector" and s.detector_classes == ["chair", "coffee table"]
    assert s.detector_input_size == 320  # --set after the manifest wins
    assert (c.kind, c.clip_image_size, cfg.graph.query_embedding) == ("clip", 32, "clip")
    assert c.clip_merges == str((d / "merges.txt").resolve())
    # one manifest, three sections
    assert set(json.loads((d / MANIFEST).read_text())) == {"format", "version", "sam", "detector", "clip"}
    os.remove(d / "clip_text.onnx")
    with pytest.raises(ConfigError, match=r"clip\.text names .*clip_text\.onnx, which does not exist"):
        manifest_overrides(d)
    with pytest.raises(ConfigError, match="no models manifest; make one with `ogscene3d models export"):
        manifest_overrides(tmp_path)
    (tmp_path / MANIFEST).write_text("{")
    with pytest.raises(ConfigError, match="not a valid models manifest"):
        manifest_overrides(tmp_path)


def test_models_export_cli_names_missing_packages_and_checkpoints(tmp_path, capsys):
    assert cli.main(["models", "export", "sam-vit-b", "--checkpoint", str(tmp_path / "no.pth"),
                     "--out", str(tmp_path / "m")]) == 2  # fmt: skip
    assert "checkpoint" in capsys.readouterr().err
    (tmp_path / "w.pt").write_bytes(b"")
    assert cli.main(["models", "export", "yolo-world", "--checkpoint", str(tmp_path / "w.pt"),
                     "--out", str(tmp_path / "m")]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "ultralytics" in err or "--classes" in err


# ------------------------------------------------------------------------------- Hugging Face CLIP


def _tiny_bpe_files(d):
    """vocab.json + merges.txt of a tiny CLIP BPE (our tokenizer's derivation of OpenAI's layout)."""
    from ogscene3d.graph.confidence import ClipTokenizer

    (d / "bpe.txt").write_text("#version: tiny\n" + "\n".join(MERGES) + "\n")
    tok = ClipTokenizer.from_files(d / "bpe.txt")
    (d / "vocab.json").write_text(json.dumps(tok.encoder))
    (d / "merges.txt").write_text("#version: 0.2\n" + "\n".join(MERGES) + "\n")
    return tok


def test_hf_clip_export_runs_through_clip_confidence(tmp_path):
    torch = pytest.importorskip("torch")
    transformers = pytest.importorskip("transformers")
    from ogscene3d.graph.confidence import ClipConfidence, clip_preprocess
    from ogscene3d.models.export import export_models

    ckpt = tmp_path / "hf-clip"
    ckpt.mkdir()
    tok = _tiny_bpe_files(ckpt)
    L = 16
    text = dict(vocab_size=len(tok.encoder), hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                num_attention_heads=2, max_position_embeddings=L, bos_token_id=tok.sot, eos_token_id=tok.eot,
                pad_token_id=0)  # fmt: skip
    vision = dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                  image_size=32, patch_size=8)  # fmt: skip
    torch.manual_seed(0)
    cfg = transformers.CLIPConfig(text_config=text, vision_config=vision, projection_dim=16)
    model = transformers.CLIPModel(cfg).eval()
    model.save_pretrained(ckpt)
    out = tmp_path / "models"
    export_models("hf-clip", ckpt, out)
    over = manifest_overrides(out)
    conf = load_config(None, over).graph.confidence
    clip = ClipConfidence.from_config(conf)
    assert clip.image_size == 32 and clip.context_length == L
    texts = ["a red chair", "green", "blue blue red"]
    ids = torch.from_numpy(tok(texts, L))
    with torch.no_grad():
        ref = model(input_ids=ids, attention_mask=(ids > 0).long(), pixel_values=torch.zeros(1, 3, 32, 32))
        want_t = torch.nn.functional.normalize(ref.text_embeds, dim=-1).numpy()
    got_t = clip.embed_texts(texts)
    got_t = got_t / np.linalg.norm(got_t, axis=1, keepdims=True)
    np.testing.assert_allclose(got_t, want_t, atol=1e-4)
    rgb = np.random.default_rng(0).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    x = torch.from_numpy(clip_preprocess(rgb, 32)[None])
    with torch.no_grad():
        want_i = model(input_ids=ids[:1], pixel_values=x).image_embeds.numpy()
    got_i = clip.embed_images([rgb])
    got_i = got_i / np.linalg.norm(got_i, axis=1, keepdims=True)
    np.testing.assert_allclose(got_i, want_i, atol=1e-4)


# ------------------------------------------------------------------------------------------ open_clip


def test_open_clip_export_runs_through_clip_confidence(tmp_path):
    torch = pytest.importorskip("torch")
    open_clip = pytest.importorskip("open_clip")
    from ogscene3d.graph.confidence import ClipConfidence
    from ogscene3d.models.export import export_open_clip_model
    from ogscene3d.models.manifest import update_manifest as upd

    torch.manual_seed(0)
    vision = open_clip.CLIPVisionCfg(layers=1, width=32, head_width=16, patch_size=8, image_size=32)
    text = open_clip.CLIPTextCfg(context_length=77, vocab_size=49408, width=32, heads=2, layers=1)
    model = open_clip.CLIP(embed_dim=16, vision_cfg=vision, text_cfg=text).eval()
    out = tmp_path / "models"
    out.mkdir()
    upd(out, "clip", {"kind": "open-clip", **export_open_clip_model(model, out)})
    clip = ClipConfidence.from_config(load_config(None, manifest_overrides(out)).graph.confidence)
    texts = ["a wooden chair", "the lamp's shade, 30 cm"]
    ref = open_clip.get_tokenizer("ViT-B-32")(texts)  # open_clip's own tokenizer and vocabulary
    np.testing.assert_array_equal(clip.tokenizer(texts, 77), ref.numpy())
    with torch.no_grad():
        want = torch.nn.functional.normalize(model.encode_text(ref), dim=-1).numpy()
    got = clip.embed_texts(texts)
    np.testing.assert_allclose(got / np.linalg.norm(got, axis=1, keepdims=True), want, atol=1e-4)


# ------------------------------------------------------------------------------------- segment-anything


def test_sam_export_runs_through_sam_onnx(tmp_path):
    torch = pytest.importorskip("torch")
    pytest.importorskip("segment_anything")
    from segment_anything.modeling import ImageEncoderViT, MaskDecoder, PromptEncoder, Sam, TwoWayTransformer
    from segment_anything.utils.onnx import SamOnnxModel

    from ogscene3d.models.export import export_sam_model
    from ogscene3d.segmentation.sam_onnx import MaskFilters, SamOnnx

    torch.manual_seed(0)
    # segment-anything's own classes at its fixed interface sizes (1024 input, 256 x 64 x 64 embeddings),
    # with a tiny ViT
    enc = ImageEncoderViT(img_size=1024, patch_size=16, embed_dim=32, depth=1, num_heads=2, out_chans=256,
                          window_size=8, global_attn_indexes=())  # fmt: skip
    prompt = PromptEncoder(embed_dim=256, image_embedding_size=(64, 64), input_image_size=(1024, 1024),
                           mask_in_chans=16)  # fmt: skip
    dec = MaskDecoder(num_multimask_outputs=3, transformer=TwoWayTransformer(depth=1, embedding_dim=256,
                      mlp_dim=64, num_heads=8), transformer_dim=256, iou_head_depth=1,
                      iou_head_hidden_dim=32)  # fmt: skip
    sam = Sam(image_encoder=enc, prompt_encoder=prompt, mask_decoder=dec).eval()
    out = tmp_path / "models"
    out.mkdir()
    entry = export_sam_model(sam, SamOnnxModel, out)
    update_manifest(out, "sam", {"kind": "sam-vit-b", **entry})
    s = load_config(None, manifest_overrides(out)).segmentation
    seg = SamOnnx(
        s.sam_encoder, s.sam_decoder, points_per_side=4, points_per_batch=4,
        filters=MaskFilters(pred_iou_thresh=0.0, stability_score_thresh=0.0, min_region_area=0),
    )  # fmt: skip
    rgb = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    image = seg.embed(rgb)
    x, _ = seg.preprocess(rgb)  # the encoder's embeddings equal the torch model's on the same input
    with torch.no_grad():
        want = sam.image_encoder(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(image.embeddings, want, atol=1e-3, rtol=1e-3)
    # the decoder takes a batch of prompts and answers as segment-anything's SamOnnxModel does
    import onnxruntime as ort

    feeds = {
        "image_embeddings": image.embeddings,
        "point_coords": np.array([[[100.0, 200.0]], [[500.0, 300.0]]], np.float32),
        "point_labels": np.ones((2, 1), np.float32),
        "mask_input": np.zeros((1, 1, 256, 256), np.float32),
        "has_mask_input": np.zeros(1, np.float32),
        "orig_im_size": np.array([48, 64], np.float32),
    }
    sess = ort.InferenceSession(s.sam_decoder, providers=["CPUExecutionProvider"])
    masks, iou, low = sess.run(None, feeds)
    with torch.no_grad():
        ref = SamOnnxModel(sam, return_single_mask=False)(*(torch.from_numpy(v) for v in feeds.values()))
    assert masks.shape == (2, 4, 48, 64) and iou.shape == (2, 4)  # the single-mask output, then 3
    np.testing.assert_allclose(iou, ref[1].numpy(), atol=1e-4)
    np.testing.assert_allclose(low, ref[2].numpy(), atol=1e-3)
    records = seg.generate(image)  # automatic mask generation through our loader
    assert all(r.crop.shape == (r.box[3] - r.box[1], r.box[2] - r.box[0]) for r in records)
    assert seg(rgb).ids.shape == (48, 64)


# ------------------------------------------------------------------------------------- YOLO-World


def test_yolo_world_export_runs_through_detector_onnx(tmp_path, monkeypatch):
    torch = pytest.importorskip("torch")
    ultralytics = pytest.importorskip("ultralytics")
    from ogscene3d.models.export import export_yolo_world_model, set_world_classes
    from ogscene3d.segmentation.detector_onnx import DetectorOnnx

    monkeypatch.chdir(tmp_path)  # Ultralytics writes its export beside the model's name
    torch.manual_seed(0)
    model = ultralytics.YOLOWorld("yolov8s-worldv2.yaml")  # Ultralytics' own model, randomly initialised
    classes = ["chair", "table", "lamp"]
    # the vocabulary from given CLIP text embeddings (set_classes would download CLIP's text encoder)
    emb = np.random.default_rng(0).normal(size=(3, int(model.model.txt_feats.shape[-1]))).astype(np.float32)
    set_world_classes(model, classes, emb)
    out = tmp_path / "models"
    entry = export_yolo_world_model(model, classes, out, image_size=160)
    update_manifest(out, "detector", {"kind": "yolo-world", **entry})
    s = load_config(None, manifest_overrides(out)).segmentation
    assert s.detector_classes == classes and s.detector_input_size == 160
    det = DetectorOnnx(s.detector, s.detector_classes, score_thresh=0.0, input_size=s.detector_input_size)
    rgb = np.random.default_rng(1).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    d = det(rgb)
    assert len(d) > 0 and set(d.names) <= set(classes)
    assert np.all(
        (d.boxes[:, 0] >= 0) & (d.boxes[:, 2] <= 160) & (d.boxes[:, 1] >= 0) & (d.boxes[:, 3] <= 120)
    )
    # the ONNX graph answers as the torch model does on the same letterboxed input
    import onnxruntime as ort

    x, _, _ = det.preprocess(rgb)
    sess = ort.InferenceSession(s.detector, providers=["CPUExecutionProvider"])
    (onnx_out,) = sess.run(None, {sess.get_inputs()[0].name: x})
    with torch.no_grad():
        ref = model.model.eval()(torch.from_numpy(x))
    ref = ref[0] if isinstance(ref, (list, tuple)) else ref  # eval mode: (predictions, raw outputs)
    np.testing.assert_allclose(onnx_out, ref.numpy(), rtol=1e-3, atol=1e-3)


def test_run_models_flag_reads_the_manifest(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["run", "--models", str(tmp_path), "--out", str(out), "--device", "cpu"]) == 2
    assert "no models manifest; make one with `ogscene3d models export" in capsys.readouterr().err
