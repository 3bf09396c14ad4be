"""The CNN–LSTM view synthesizer: ResNet-18 backbone, sequence model and decoders."""

from sparself.model.backbone import (
    NO_WEIGHTS,
    RESNET18_URL,
    ResNet18,
    default_weights,
    hub_weights_path,
    load_resnet18_weights,
)
from sparself.model.cnn_lstm import CNNLSTM, PoseNorm, positional_encoding, sequence_layout
from sparself.model.decoders import DECODERS, FCDecoder, SweepDecoder, build_decoder, sweep_volume

__all__ = [
    "NO_WEIGHTS",
    "RESNET18_URL",
    "ResNet18",
    "default_weights",
    "hub_weights_path",
    "load_resnet18_weights",
    "CNNLSTM",
    "PoseNorm",
    "positional_encoding",
    "sequence_layout",
    "DECODERS",
    "FCDecoder",
    "SweepDecoder",
    "build_decoder",
    "sweep_volume",
]
