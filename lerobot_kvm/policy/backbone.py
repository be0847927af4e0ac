"""CPU-sized VLA-style backbone: conv vision tokens + proprio + context + action queries through a
pre-LN transformer encoder whose first layers are prefix-tuned by the CODA prompt, and a linear action head.

Language never enters the backbone: it only shapes the prompt (through the CODA query), so the prompt, and
hence the KVM's skill weighting, is what controls behaviour.
"""

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn


class ConvEncoder(nn.Module):
    """Stride-2 3x3 conv stack (96 -> 48 -> 24 -> 12 -> 6 with four stages), 1x1-projected to tokens."""

    def __init__(self, channels: list[int], dim_model: int):
        super().__init__()
        layers: list[nn.Module] = []
        in_ch = 3
        for out_ch in channels:
            layers += [
                nn.Conv2d(in_ch, out_ch, kernel_size=3, stride=2, padding=1),
                nn.GroupNorm(min(8, out_ch), out_ch),
                nn.ReLU(inplace=True),
            ]
            in_ch = out_ch
        self.stages = nn.Sequential(*layers)
        self.proj = nn.Conv2d(in_ch, dim_model, kernel_size=1)

    @staticmethod
    def grid_size(height: int, width: int, n_stages: int) -> tuple[int, int]:
        """Spatial size after `n_stages` stride-2 convs with padding 1 (ceil halving)."""
        for _ in range(n_stages):
            height, width = (height + 1) // 2, (width + 1) // 2
        return height, width

    def forward(self, images: Tensor) -> Tensor:
        """[N, 3, H, W] -> [N, h*w, dim_model]."""
        return self.proj(self.stages(images)).flatten(2).transpose(1, 2)


class PrefixSelfAttention(nn.Module):
    """Multi-head self-attention whose keys and values can be extended by prompt prefixes (prefix-tuning)."""

    def __init__(self, dim_model: int, n_heads: int):
        super().__init__()
        self.n_heads = n_heads
        self.qkv = nn.Linear(dim_model, 3 * dim_model)
        self.out = nn.Linear(dim_model, dim_model)

    def _heads(self, x: Tensor) -> Tensor:
        return x.unflatten(-1, (self.n_heads, -1)).transpose(1, 2)  # [B, H, T, Dh]

    def forward(self, x: Tensor, prompt: Tensor | None = None) -> Tensor:
        """x [B, T, D]; prompt [B, Lp, D]: first half prepended to the keys, second half to the values."""
        q, k, v = self.qkv(x).chunk(3, dim=-1)
        if prompt is not None:
            prefix_k, prefix_v = prompt.chunk(2, dim=1)
            k = torch.cat([prefix_k, k], dim=1)
            v = torch.cat([prefix_v, v], dim=1)
        attended = F.scaled_dot_product_attention(self._heads(q), self._heads(k), self._heads(v))
        return self.out(attended.transpose(1, 2).flatten(2))


class PromptedEncoderLayer(nn.Module):
    """Pre-LN transformer encoder layer with an optional attention prefix.

    Dropout acts on the two residual branches only: on CPU, dropout masks over attention weights and the wide
    feed-forward activations cost ~20% of a training step for little regularisation at this size.
    """

    def __init__(self, dim_model: int, n_heads: int, dim_feedforward: int, dropout: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim_model)
        self.attn = PrefixSelfAttention(dim_model, n_heads)
        self.norm2 = nn.LayerNorm(dim_model)
        self.ff = nn.Sequential(
            nn.Linear(dim_model, dim_feedforward),
            nn.GELU(),
            nn.Linear(dim_feedforward, dim_model),
        )
        self.drop = nn.Dropout(dropout)

    def forward(self, x: Tensor, prompt: Tensor | None = None) -> Tensor:
        x = x + self.drop(self.attn(self.norm1(x), prompt))
        return x + self.drop(self.ff(self.norm2(x)))


class PromptedBackbone(nn.Module):
    """Tokenises an observation, runs the prefix-tuned transformer and decodes an action chunk."""

    def __init__(
        self,
        *,
        image_shape: tuple[int, int, int],
        n_cameras: int,
        state_dim: int,
        context_dim: int,
        action_dim: int,
        chunk_size: int,
        vision_channels: list[int],
        dim_model: int,
        n_layers: int,
        n_heads: int,
        dim_feedforward: int,
        dropout: float,
    ):
        super().__init__()
        self.image_size = (image_shape[1], image_shape[2])  # every camera image is resized to it
        grid_h, grid_w = ConvEncoder.grid_size(image_shape[1], image_shape[2], len(vision_channels))
        self.vision = ConvEncoder(vision_channels, dim_model)
        self.row_embed = nn.Parameter(torch.randn(grid_h, 1, dim_model) * 0.02)
        self.col_embed = nn.Parameter(torch.randn(1, grid_w, dim_model) * 0.02)
        self.camera_embed = nn.Parameter(torch.randn(n_cameras, 1, dim_model) * 0.02)
        self.state_proj = nn.Linear(state_dim, dim_model)
        self.context_proj = nn.Linear(context_dim, dim_model)
        self.type_embed = nn.Parameter(torch.randn(2, dim_model) * 0.02)  # proprio, context
        self.action_queries = nn.Parameter(torch.randn(chunk_size, dim_model) * 0.02)
        self.layers = nn.ModuleList(
            PromptedEncoderLayer(dim_model, n_heads, dim_feedforward, dropout) for _ in range(n_layers)
        )
        self.final_norm = nn.LayerNorm(dim_model)
        self.action_head = nn.Linear(dim_model, action_dim)

    def resize(self, image: Tensor) -> Tensor:
        """[B, 3, H, W] at the backbone's input size (antialiased, so a downscaled image does not alias)."""
        if tuple(image.shape[-2:]) == self.image_size:
            return image
        return F.interpolate(image, size=self.image_size, mode="bilinear", antialias=True, align_corners=False)

    def forward(self, images: list[Tensor], state: Tensor, context: Tensor, prompts: Tensor | None) -> Tensor:
        """images: per camera [B, 3, H, W], any H, W; state [B, S]; context [B, C]; prompts [L_p, B, Lp, D] for
        the first L_p layers (or None). Returns normalized actions [B, chunk, action_dim]."""
        batch = state.shape[0]
        n_cams = len(images)
        images = [self.resize(image) for image in images]
        pos = (self.row_embed + self.col_embed).flatten(0, 1)  # [h*w, D]
        vis = self.vision(torch.cat(images, dim=0)).unflatten(0, (n_cams, batch))  # [cams, B, h*w, D]
        vis = vis + pos + self.camera_embed[:n_cams, None]
        tokens = torch.cat(
            [
                vis.transpose(0, 1).flatten(1, 2),
                (self.state_proj(state) + self.type_embed[0]).unsqueeze(1),
                (self.context_proj(context) + self.type_embed[1]).unsqueeze(1),
                self.action_queries.expand(batch, -1, -1),
            ],
            dim=1,
        )
        n_prompted = 0 if prompts is None else prompts.shape[0]
        for i, layer in enumerate(self.layers):
            tokens = layer(tokens, prompts[i] if i < n_prompted else None)
        queries = self.final_norm(tokens[:, -self.action_queries.shape[0] :])
        return self.action_head(queries)
