"""GLSL programs shipped with the toolkit: the player's and the synthetic-scene renderer's.

Shaders are plain ``.glsl``/``.vert``/``.frag`` files in this folder; read them with
:func:`shader_source` so that an installed wheel finds them as well as a checkout.
"""

from __future__ import annotations

from importlib import resources


def shader_source(name: str) -> str:
    """Text of the shader file ``name`` (e.g. ``"player.frag"``)."""
    try:
        return resources.files(__name__).joinpath(name).read_text(encoding="utf-8")
    except FileNotFoundError:
        available = sorted(
            p.name for p in resources.files(__name__).iterdir() if not p.name.startswith("_")
        )
        raise FileNotFoundError(
            f"no shader named {name!r}; available: {', '.join(available) or 'none'}"
        ) from None
