"""Loading user-supplied ONNX models with onnxruntime: provider choice, I/O checks, clear errors.

onnxruntime is imported lazily so that ``import ogscene3d`` works without it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

import numpy as np

from ..config import ExecutionProvider
from ..errors import ConfigError, ModelError

log = logging.getLogger(__name__)

# onnxruntime's tensor type strings -> numpy dtypes (the ones segmentation exports use).
_ORT_DTYPES = {
    "tensor(float)": np.float32,
    "tensor(float16)": np.float16,
    "tensor(double)": np.float64,
    "tensor(uint8)": np.uint8,
    "tensor(int8)": np.int8,
    "tensor(int32)": np.int32,
    "tensor(int64)": np.int64,
    "tensor(bool)": np.bool_,
}


@dataclass(frozen=True)
class TensorInfo:
    """Name, shape (ints for fixed dims, None for symbolic ones) and numpy dtype of a model input/output."""

    name: str
    shape: tuple[int | None, ...]
    dtype: Any

    def describe(self) -> str:
        dims = ", ".join("?" if d is None else str(d) for d in self.shape)
        return f"{self.name}[{dims}] {np.dtype(self.dtype).name}"


def _tensor_info(arg: Any) -> TensorInfo:
    shape = tuple(int(d) if isinstance(d, int) and d >= 0 else None for d in (arg.shape or []))
    return TensorInfo(arg.name, shape, _ORT_DTYPES.get(arg.type, np.float32))


def choose_providers(provider: str = "auto") -> list[str]:
    """onnxruntime execution providers for ``provider`` in {"auto", "cpu", "cuda"}.

    "cuda" when the CUDA provider is not available (CPU-only onnxruntime wheel, no GPU) falls back
    to the CPU with a logged warning rather than failing: the results are the same, only slower.
    """
    import onnxruntime as ort

    provider = (provider or "auto").lower()
    if provider not in get_args(ExecutionProvider):
        raise ConfigError(f"segmentation.execution_provider must be auto, cpu or cuda, got {provider!r}")
    available = ort.get_available_providers()
    has_cuda = "CUDAExecutionProvider" in available
    if provider == "cpu":
        return ["CPUExecutionProvider"]
    if has_cuda:
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    if provider == "cuda":
        log.warning(
            "CUDA execution provider requested but onnxruntime offers only %s (install onnxruntime-gpu); "
            "running the segmentation models on the CPU",
            available,
        )
    return ["CPUExecutionProvider"]


class OnnxModel:
    """An onnxruntime session plus the model's declared inputs/outputs, for one user-supplied file.

    ``what`` names the model's role ("SAM encoder", ...) in error messages.
    """

    def __init__(self, path: str | Path | None, what: str, provider: str = "auto") -> None:
        if path is None or str(path) == "":
            raise ConfigError(f"no {what} ONNX file given")
        self.path = Path(path).expanduser()
        self.what = what
        if not self.path.is_file():
            raise ModelError(f"{self.path}: {what} ONNX file does not exist")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.log_severity_level = 3  # onnxruntime's own warnings (e.g. unused initialisers) are noise here
        providers = choose_providers(provider)
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=providers)
        except Exception as e:  # onnxruntime raises its own exception types for corrupt/invalid graphs
            raise ModelError(f"{self.path}: cannot load the {what} as an ONNX model ({e})") from e
        self.inputs = {a.name: _tensor_info(a) for a in self.session.get_inputs()}
        self.outputs = {a.name: _tensor_info(a) for a in self.session.get_outputs()}
        used = self.session.get_providers()
        if providers[0] not in used:  # e.g. CUDA libraries missing: onnxruntime fell back on its own
            log.warning("%s %s: %s could not be used, running on %s", what, self.path, providers[0], used)
        log.info("loaded the %s %s (%s)", what, self.path.name, ", ".join(used))

    def describe(self) -> str:
        ins = ", ".join(t.describe() for t in self.inputs.values())
        outs = ", ".join(t.describe() for t in self.outputs.values())
        return f"inputs ({ins}), outputs ({outs})"

    def error(self, problem: str, expected: str) -> ModelError:
        """A ModelError naming the file, the problem, what was expected and what the file declares."""
        return ModelError(
            f"{self.path}: {problem} for a {self.what}; expected {expected}; found {self.describe()}"
        )

    def require(self, inputs: Iterable[str] = (), outputs: Iterable[str] = (), expected: str = "") -> None:
        """Raise a ModelError unless every named input and output is declared by the model."""
        missing_in = [n for n in inputs if n not in self.inputs]
        missing_out = [n for n in outputs if n not in self.outputs]
        if missing_in or missing_out:
            what = []
            if missing_in:
                what.append(f"missing input(s) {missing_in}")
            if missing_out:
                what.append(f"missing output(s) {missing_out}")
            raise self.error(" and ".join(what), expected)

    def run(self, feeds: dict[str, np.ndarray], outputs: Sequence[str] | None = None) -> list[np.ndarray]:
        """Run the model; feeds are cast to the declared input dtypes. Runtime failures become ModelError."""
        cast = {k: np.ascontiguousarray(v, dtype=self.inputs[k].dtype) for k, v in feeds.items()}
        try:
            return self.session.run(list(outputs) if outputs is not None else None, cast)
        except Exception as e:
            shapes = ", ".join(f"{k}{list(v.shape)}" for k, v in cast.items())
            raise ModelError(f"{self.path}: the {self.what} failed on inputs {shapes} ({e})") from e
