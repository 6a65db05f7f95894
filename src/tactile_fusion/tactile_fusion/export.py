"""Export to ONNX: the float32 graph, an int8-quantized variant (last layer kept in float) and a float16 graph.

Every graph has the same interface as the model's `forward`:
  images    (B, C, H, W) uint8   current frames, cameras in the model's camera_ids order
  reference (C, H, W)    uint8   the cameras' no-contact frames
  bin_forces_n (B, rows, cols, 3) float32 newtons
The uint8 -> float conversion and the difference are inside the graph, so no caller can get the wrap-around
of uint8 differences wrong. Each graph also names, in its metadata, the model.json fields it has built in (camera
order, bin grid, force scale, components, Fz threshold, model config: artifacts.model_fields, each as JSON), so that
a graph and a model.json of two different models, or a model.json edited after export, are told apart on loading
(`graph_mismatches`).
"""

from __future__ import annotations

import copy
import io
import json
import warnings
from pathlib import Path

import onnx
import torch
from torch import nn

from tactile_fusion.artifacts import (
    ModelFileError,
    discard,
    mismatched_fields,
    model_fields,
    replace_file,
    unwritable,
)
from tactile_fusion.model import ForceFusionNet, difference_images

#: ONNX opset of the exported graphs (supported by onnxruntime >= 1.13 and the quantization tools).
OPSET = 17
INPUT_NAMES = ("images", "reference")
OUTPUT_NAME = "bin_forces_n"


class _Float16Graph(nn.Module):
    """The model computed in float16 from the difference image on; uint8 in, float32 newtons out.

    The difference (and its brightness gain, a sum over 16 384 pixels of up to 255^2) is computed in float32:
    in float16 the sums would overflow above 65 504.
    """

    def __init__(self, model: ForceFusionNet):
        super().__init__()
        self.model = copy_to_half(model)

    def forward(self, images: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        difference = difference_images(images, reference).to(torch.float16)
        return self.model.to_newtons(self.model.forward_normalised(difference))


def copy_to_half(model: ForceFusionNet) -> ForceFusionNet:
    """A float16 copy of `model` in evaluation mode (the original is untouched)."""
    return copy.deepcopy(model).eval().half()


def export_onnx(model: ForceFusionNet, path: str | Path, precision: str = "fp32") -> Path:
    """Write `model` as an ONNX graph (precision "fp32" or "fp16") and check it with onnx.checker."""
    if precision not in ("fp32", "fp16"):
        raise ValueError(f"export_onnx: precision must be 'fp32' or 'fp16' (int8: quantize_int8), got {precision!r}")
    model = model.eval()
    graph = model if precision == "fp32" else _Float16Graph(model)
    c, size = model.n_cameras, model.config.image_size
    example = (torch.zeros(1, c, size, size, dtype=torch.uint8), torch.zeros(c, size, size, dtype=torch.uint8))
    proto = onnx.load_from_string(onnx_bytes(graph, example, OUTPUT_NAME))
    onnx.helper.set_model_props(proto, {key: json.dumps(value) for key, value in model_fields(model).items()})
    onnx.checker.check_model(proto, full_check=True)
    return save_graph(proto, Path(path))


def save_graph(proto: onnx.ModelProto, path: Path) -> Path:
    """Write the graph `proto` to `path` whole or not at all (artifacts.replace_file), so that a write that fails (a
    full disk) leaves the previous graph as it was; ModelFileError naming the file if it cannot be written."""
    try:
        replace_file(path, proto.SerializeToString())
    except OSError as exc:
        raise _unwritable(path, exc) from exc
    return path


def _unwritable(path: Path, exc: OSError) -> ModelFileError:
    """artifacts.unwritable for a graph file: export again."""
    return unwritable(path, exc, f"export again (tactile-fusion export --model {path.parent})")


def graph_mismatches(metadata: dict[str, str], fields: dict) -> list[str]:
    """artifacts.mismatched_fields of what a graph's metadata names (JSON; an entry that is not JSON is compared as
    its text, which no field equals). Graphs exported by older versions name fewer fields (none, or only
    fz_threshold_n)."""
    return mismatched_fields({key: _json_or_text(text) for key, text in metadata.items()}, fields, "the graph")


def _json_or_text(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


def onnx_bytes(graph: nn.Module, example: tuple[torch.Tensor, torch.Tensor], output_name: str) -> bytes:
    """`graph` (inputs INPUT_NAMES, evaluation mode) as a serialised ONNX graph whose inputs and output have a free
    batch axis, traced with `example`."""
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        # torch >= 2.9 marks the TorchScript exporter deprecated in favour of dynamo=True, which needs
        # onnxscript (not a dependency of this project); the TorchScript path is still supported and tested.
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", FutureWarning)
        torch.onnx.export(graph, example, buffer, input_names=list(INPUT_NAMES), output_names=[output_name],
                          dynamic_axes={"images": {0: "batch"}, output_name: {0: "batch"}}, opset_version=OPSET,
                          do_constant_folding=True, dynamo=False)
    return buffer.getvalue()


def quantize_int8(fp32_path: str | Path, int8_path: str | Path) -> Path:
    """Dynamic int8 quantization of the CNN's fully connected layers (per-channel int8 weights; each call quantizes
    their input from its own range, taken over all frames of the call).

    Dynamic rather than static (calibrated) quantization, measured on the previous shipped model (24 x 24 grid;
    docs/learning.md): the ReLU features have no upper bound, so fixed activation ranges clip frames beyond the
    calibration data (21 mN in the worst test bin with 1024 calibration frames, 77 mN with 64); with ranges taken
    per call it was 8.9 mN (per-bin Fz RMSE 3.672 against 3.708 mN, float32 3.669), at the same speed, and export
    needs no training data.
    What stays in float, and why:
    - the fusion layer (the regression head, the MatMul/Gemm nodes after the last activation) and the final
      scaling: int8 steps of a head whose outputs span four orders of magnitude (most bins ~0, peaks ~0.5 N)
      would swamp the small forces;
    - the convolutions: with 1 to 16 channels, ONNX Runtime's int8 convolution kernels are slower on x86 than
      its float32 ones (1.7 ms against 0.6 ms per frame) and they added up to 0.14 N per bin of error.
    """
    from onnxruntime.quantization import QuantType, quant_pre_process, quantize_dynamic

    fp32_path, int8_path = Path(fp32_path), Path(int8_path)
    prepared = int8_path.with_name(int8_path.stem + ".prep.onnx")
    quantized = int8_path.with_name(int8_path.stem + ".quantized.onnx")
    try:
        int8_path.unlink(missing_ok=True)  # a graph of another model must not stay behind if this one fails
        quant_pre_process(str(fp32_path), str(prepared), skip_symbolic_shape=True)
        fusion = fusion_node_names(prepared)
        # Dynamic quantization first rewrites every Gemm as MatMul + Add, the MatMul named "<Gemm name>_MatMul":
        # the fusion layer is excluded under both names.
        quantize_dynamic(str(prepared), str(quantized), weight_type=QuantType.QInt8, per_channel=True,
                         op_types_to_quantize=["MatMul", "Gemm"],
                         nodes_to_exclude=[*fusion, *(f"{name}_MatMul" for name in fusion)])
        proto = onnx.load(str(quantized))
    except OSError as exc:  # the intermediate graphs beside it could not be written
        raise _unwritable(int8_path, exc) from exc
    finally:
        discard(prepared)
        discard(quantized)
    onnx.checker.check_model(proto, full_check=True)
    # Checked on the result, by operator type (not by the names the exclusion relied on).
    head = _after_last_activation(proto.graph.node)
    if any(node.op_type in INT8_OPS for node in head) or not any(node.op_type in FLOAT_PRODUCTS for node in head):
        raise RuntimeError(f"quantize_int8: ONNX Runtime quantized the fusion layer of {fp32_path} (did the names "
                           "of its nodes change?); it must stay in float")
    metadata = {p.key: p.value for p in onnx.load(str(fp32_path), load_external_data=False).metadata_props}
    onnx.helper.set_model_props(proto, metadata)  # the float graph's, the Fz threshold's included
    return save_graph(proto, int8_path)


#: Operators of a quantized matrix product, and of a float one.
INT8_OPS = ("DynamicQuantizeLinear", "MatMulInteger", "QuantizeLinear", "DequantizeLinear", "QLinearMatMul",
            "MatMulIntegerToFloat", "DynamicQuantizeMatMul")
FLOAT_PRODUCTS = ("MatMul", "Gemm")


def fusion_node_names(path: str | Path) -> list[str]:
    """Names of the graph's nodes after the last activation (the camera features' Sigmoid or Relu): the fusion
    layer, reshape and force scaling."""
    return [node.name for node in _after_last_activation(onnx.load(str(path)).graph.node)]


def _after_last_activation(nodes) -> list:
    """The nodes after the last Sigmoid or Relu of a (topologically sorted) graph."""
    last_activation = max(i for i, node in enumerate(nodes) if node.op_type in ("Sigmoid", "Relu"))
    return list(nodes[last_activation + 1:])
