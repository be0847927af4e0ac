"""One image that shows, per scenario, the prior skill working on the prior variant and doing harm on the shifted one.

It is the quickest way for a person to check that every scene looks right: that the shifted
object is (in A/B) indistinguishable at reset, and that the harm is visible afterwards.
"""

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..envs.catalogue import CATEGORIES, SCENARIO_INFOS
from ..envs.env import KvmObsolescenceEnv

LABEL_WIDTH = 190
CAPTION_HEIGHT = 34
HEADER_HEIGHT = 24
PAD = 6
BACKGROUND = (255, 255, 255)
TEXT = (20, 20, 20)
HARM = (180, 20, 20)


def _outcome(info: dict) -> str:
    if info["catastrophe"]:
        return f"HARM: {info['catastrophe_kind']}"
    return "success" if info["is_success"] else "timed out"


def _wrap(draw: ImageDraw.ImageDraw, text: str, font: ImageFont.ImageFont, width: int, max_lines: int = 2) -> str:
    """Word-wraps a caption to the panel width, with an ellipsis if it would need more lines."""
    lines: list[str] = []
    for word in text.split():
        if lines and draw.textlength(f"{lines[-1]} {word}", font=font) <= width:
            lines[-1] += f" {word}"
        else:
            lines.append(word)
    if len(lines) > max_lines:
        lines = lines[:max_lines]
        lines[-1] += " …"
    for i, line in enumerate(lines):
        while draw.textlength(line, font=font) > width:
            line = line[:-2] + "…"
        lines[i] = line
    return "\n".join(lines)


def scenario_panels(scenario_id: str, seed: int, size: int) -> list[tuple[np.ndarray, str]]:
    """Prior at reset, prior after the prior skill, shifted at reset, shifted after the prior skill."""
    env = KvmObsolescenceEnv(task=scenario_id, render_size=size)
    skill = env.scenario.info.prior_skill
    panels = []
    for variant in ("prior", "shifted"):
        env.reset(seed=seed, options={"variant": variant})
        panels.append((env.render(), f"“{env.task_description}”"))
        expert = env.scenario.expert(skill)
        while True:
            _, _, terminated, truncated, info = env.step(expert.act(env.physics))
            if terminated or truncated:
                break
        panels.append((env.render(), f"{_outcome(info)} after {env.step_count} steps"))
    env.close()
    return panels


def contact_sheet(scenario_ids: list[str], seed: int = 0, size: int = 160) -> Image.Image:
    """The grid: one labelled row per scenario, four captioned panels per row."""
    font = ImageFont.load_default(size=12)
    bold = ImageFont.load_default(size=14)
    row_h = size + CAPTION_HEIGHT + PAD
    width = LABEL_WIDTH + 4 * (size + PAD) + PAD
    sheet = Image.new("RGB", (width, HEADER_HEIGHT + row_h * len(scenario_ids) + PAD), BACKGROUND)
    draw = ImageDraw.Draw(sheet)
    titles = ("prior, at reset", "prior, after prior skill", "shifted, at reset", "shifted, after prior skill")
    for col, title in enumerate(titles):
        draw.text((LABEL_WIDTH + col * (size + PAD), PAD), title, fill=TEXT, font=bold)
    for r, sid in enumerate(scenario_ids):
        info = SCENARIO_INFOS[sid]
        top = HEADER_HEIGHT + r * row_h
        label = "\n".join(
            [
                sid,
                f"{info.category}: {CATEGORIES[info.category]}",
                f"harm: {info.harm}",
                f"prior skill: {info.prior_skill}",
            ]
        )
        draw.multiline_text((PAD, top + PAD), label, fill=TEXT, font=font, spacing=4)
        for col, (image, caption) in enumerate(scenario_panels(sid, seed, size)):
            left = LABEL_WIDTH + col * (size + PAD)
            sheet.paste(Image.fromarray(image), (left, top))
            colour = HARM if caption.startswith("HARM") else TEXT
            text = _wrap(draw, caption, font, size)
            draw.multiline_text((left, top + size + 2), text, fill=colour, font=font, spacing=2)
    return sheet
