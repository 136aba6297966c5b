"""CLIP node confidence with tiny ONNX encoders built by onnx.helper, and the CLIP BPE tokenizer."""

import json

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from ogscene3d.config import GraphConfig, NodeConfidenceConfig
from ogscene3d.errors import ConfigError, ModelError
from ogscene3d.graph import ClipConfidence, ClipTokenizer, SceneGraph, SceneNode, build_confidence
from ogscene3d.graph.confidence import CLIP_MEAN, CLIP_STD, _bytes_to_unicode
from ogscene3d.graph.types import CaptionRequest, Crop, ObservationSet, SceneContext

MERGES = ["g r", "gr e", "gre e", "gree n</w>", "r e", "re d</w>", "b l", "bl u", "blu e</w>"]
S = 16  # image size of the tiny image model
L = 24  # context length of the tiny text model


def _write_bpe(tmp_path):
    path = tmp_path / "bpe_tiny.txt"
    path.write_text("#version: tiny\n" + "\n".join(MERGES) + "\n")
    return path


def _models(tmp_path, tok: ClipTokenizer, static_batch: bool = False, size: int | str = S):
    batch = 1 if static_batch else "N"
    # image: mean over pixels of the normalised channels -> a 3-D "embedding"
    img = helper.make_graph(
        [helper.make_node("ReduceMean", ["pixel_values"], ["image_embeds"], axes=[2, 3], keepdims=0)],
        "img",
        [helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, [batch, 3, size, size])],
        [helper.make_tensor_value_info("image_embeds", TensorProto.FLOAT, [batch, 3])],
    )
    # text: sum of per-token embeddings; colour words point along their channel
    V = len(tok.encoder)
    table = np.zeros((V, 3), np.float32)
    table[tok.encoder["red</w>"]] = [1, 0, 0]
    table[tok.encoder["green</w>"]] = [0, 1, 0]
    table[tok.encoder["blue</w>"]] = [0, 0, 1]
    txt = helper.make_graph(
        [
            helper.make_node("Gather", ["table", "input_ids"], ["tok"], axis=0),
            helper.make_node("ReduceSum", ["tok", "axes"], ["text_embeds"], keepdims=0),
        ],
        "txt",
        [
            helper.make_tensor_value_info("input_ids", TensorProto.INT64, [batch, L]),
            helper.make_tensor_value_info("attention_mask", TensorProto.INT64, [batch, L]),
        ],
        [helper.make_tensor_value_info("text_embeds", TensorProto.FLOAT, [batch, 3])],
        initializer=[
            helper.make_tensor("table", TensorProto.FLOAT, table.shape, table.ravel()),
            helper.make_tensor("axes", TensorProto.INT64, [1], [1]),
        ],
    )
    paths = []
    for g, name in ((img, "image.onnx"), (txt, "text.onnx")):
        m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 13)])
        m.ir_version = 8
        onnx.checker.check_model(m)
        onnx.save(m, tmp_path / name)
        paths.append(str(tmp_path / name))
    return paths


def test_tokenizer_bpe_and_hf_format(tmp_path):
    tok = ClipTokenizer.from_files(_write_bpe(tmp_path))
    assert len(tok.encoder) == 512 + len(MERGES) + 2
    ids = tok(["Red  blue!", "green"], context_length=L)
    assert ids.shape == (2, L) and ids.dtype == np.int64
    assert ids[0, :5].tolist() == [
        tok.sot,
        tok.encoder["red</w>"],
        tok.encoder["blue</w>"],
        tok.encoder["!</w>"],
        tok.eot,
    ]
    assert ids[0, 5:].tolist() == [0] * (L - 5)
    long = tok(["red " * 40], context_length=L)[0]
    assert long[-1] == tok.eot and long[0] == tok.sot  # truncated, still terminated
    # unmerged word falls back to byte-level pieces
    b2u = _bytes_to_unicode()
    assert tok.encode("xy") == [tok.encoder[b2u[ord("x")]], tok.encoder[b2u[ord("y")] + "</w>"]]
    # the Hugging Face layout (vocab.json + merges.txt) gives the same ids
    (tmp_path / "vocab.json").write_text(json.dumps(tok.encoder))
    (tmp_path / "merges.txt").write_text("#version: 0.2\n" + "\n".join(MERGES) + "\n")
    hf = ClipTokenizer.from_files(tmp_path / "vocab.json")
    assert (hf(["Red  blue!", "green"], L) == ids).all()
    with pytest.raises(ModelError, match="does not exist"):
        ClipTokenizer.from_files(tmp_path / "nope.txt")
    (tmp_path / "bad.txt").write_text("#v\na b c\n")
    with pytest.raises(ModelError, match="malformed"):
        ClipTokenizer.from_files(tmp_path / "bad.txt")


def _request(node_id, caption, colour):
    img = np.zeros((20, 30, 3), np.uint8)
    img[:] = colour
    node = SceneNode.from_points(
        node_id, np.random.default_rng(node_id).uniform(0, 1, (30, 3)), confidences=np.full(30, 0.42)
    )
    node.caption = caption
    obs = ObservationSet(context=Crop(img, 0, 600))
    return CaptionRequest(node, obs, SceneContext(np.array([0.0, -1.0, 0.0]), 0.0, 1.0))


@pytest.mark.parametrize("static_batch", [False, True])
def test_clip_confidence_matches_reference(tmp_path, static_batch):
    bpe = _write_bpe(tmp_path)
    tok = ClipTokenizer.from_files(bpe)
    image_path, text_path = _models(tmp_path, tok, static_batch)
    clip = ClipConfidence(image_path, text_path, tok, execution_provider="cpu")
    assert clip.image_size == S and clip.context_length == L
    reqs = [
        _request(0, "a red mug", (255, 0, 0)),
        _request(1, "a blue mug", (255, 0, 0)),
        _request(2, "a green plant", (0, 255, 0)),
        _request(3, "", (0, 255, 0)),  # no caption -> fallback (mean Gaussian confidence)
    ]
    reqs.append(CaptionRequest(reqs[0].node, ObservationSet(), reqs[0].context))  # no crop -> fallback
    reqs[-1].node = SceneNode.from_points(4, np.zeros((3, 3)), confidences=np.full(3, 0.7))
    reqs[-1].node.caption = "red"
    scores = clip.score(reqs)

    def expected(colour, axis):
        pix = (np.asarray(colour, np.float32) / 255.0 - CLIP_MEAN) / CLIP_STD
        return max(0.0, float(pix[axis] / np.linalg.norm(pix)))

    assert scores[0] == pytest.approx(expected((255, 0, 0), 0), abs=1e-5)
    assert scores[1] == pytest.approx(expected((255, 0, 0), 2), abs=1e-5) and scores[1] < scores[0]
    assert scores[2] == pytest.approx(expected((0, 255, 0), 1), abs=1e-5)
    assert scores[3] == pytest.approx(0.42) and scores[4] == pytest.approx(0.7)
    # text embeddings are also what query embedding uses
    te = clip.embed_texts(["red", "blue"])
    assert np.allclose(te, [[1, 0, 0], [0, 0, 1]], atol=1e-6)


def test_clip_from_config_and_errors(tmp_path):
    bpe = _write_bpe(tmp_path)
    image_path, text_path = _models(tmp_path, ClipTokenizer.from_files(bpe))
    cfg = NodeConfidenceConfig(
        kind="clip", clip_image=image_path, clip_text=text_path, clip_vocab=str(bpe), execution_provider="cpu"
    )
    assert isinstance(build_confidence(cfg), ClipConfidence)
    with pytest.raises(ConfigError, match="clip_text"):
        build_confidence(NodeConfidenceConfig(kind="clip", clip_image=image_path, clip_vocab=str(bpe)))
    with pytest.raises(ModelError, match="does not exist"):
        build_confidence(
            NodeConfidenceConfig(
                kind="clip", clip_image="/nope.onnx", clip_text=text_path, clip_vocab=str(bpe)
            )
        )
    (tmp_path / "junk.onnx").write_bytes(b"not onnx")
    with pytest.raises(ModelError, match="could not be loaded"):
        build_confidence(
            NodeConfidenceConfig(
                kind="clip", clip_image=str(tmp_path / "junk.onnx"), clip_text=text_path, clip_vocab=str(bpe)
            )
        )
    with pytest.raises(ModelError, match="integer token-id input"):  # models swapped
        build_confidence(
            NodeConfidenceConfig(
                kind="clip", clip_image=image_path, clip_text=image_path, clip_vocab=str(bpe)
            )
        )


def test_clip_image_size_of_a_dynamic_export(tmp_path):
    """A dynamic image input does not say the model's size: 224 unless graph.confidence.clip_image_size says
    (a 336-pixel model); a static export's own size wins, and a setting that disagrees is an error."""
    bpe = _write_bpe(tmp_path)
    tok = ClipTokenizer.from_files(bpe)
    image_path, text_path = _models(tmp_path, tok, size="S")
    assert ClipConfidence(image_path, text_path, tok, execution_provider="cpu").image_size == 224
    paths = {"clip_image": image_path, "clip_text": text_path, "clip_vocab": str(bpe)}
    cfg = NodeConfidenceConfig(kind="clip", execution_provider="cpu", clip_image_size=336, **paths)
    clip = build_confidence(cfg)
    assert clip.image_size == 336
    assert clip.score([_request(0, "a red mug", (255, 0, 0))])[0] > 0.5  # the model runs at 336
    static_image, _ = _models(tmp_path, tok)
    with pytest.raises(ModelError, match=f"takes {S}x{S} images, but graph.confidence.clip_image_size"):
        ClipConfidence(static_image, text_path, tok, "cpu", image_size=336)
    assert ClipConfidence(static_image, text_path, tok, "cpu", image_size=S).image_size == S


def test_clip_query_embedding(tmp_path):
    bpe = _write_bpe(tmp_path)
    image_path, text_path = _models(tmp_path, ClipTokenizer.from_files(bpe))
    cfg = GraphConfig(query_embedding="clip", query_min_similarity=0.5)
    cfg.confidence = NodeConfidenceConfig(
        kind="clip", clip_image=image_path, clip_text=text_path, clip_vocab=str(bpe), execution_provider="cpu"
    )
    g = SceneGraph(cfg)
    for i, (tag, cap) in enumerate([("thing", "a red object"), ("item", "a blue object")]):
        n = SceneNode.from_points(i, np.zeros((3, 3)))
        n.tag, n.caption = tag, cap
        g.nodes[i] = n
    hits = g.query_scored("red")
    assert [n.id for n, _ in hits] == [0]  # text match and embedding agree
    hits = g.query_scored("green blue")  # no text match; embedding (0,1,1)/sqrt2 . (0,0,1) = 0.707
    assert [n.id for n, _ in hits] == [1] and hits[0][1] == pytest.approx(2**-0.5, abs=1e-5)


def test_missing_tokenizers_package_names_what_to_install(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "tokenizers", None)  # import tokenizers -> ImportError
    with pytest.raises(ModelError, match=r"pip install tokenizers \(or pip install 'ogscene3d\[clip\]'\)"):
        ClipTokenizer.from_files(_write_bpe(tmp_path))
