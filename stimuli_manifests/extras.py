"""Which install extra provides which optional library, and the message when one is missing.

The base install is the participant's (manifests and the player); everything heavier comes
from an extra (``pip install 'cgvq-toolkit[analysis]'`` ...). Commands import their heavy
libraries lazily, so a missing one surfaces as ``ModuleNotFoundError`` at the point of use;
:func:`explain_missing` turns that into the one-line :class:`MissingExtraError`.
"""

from __future__ import annotations

from .errors import MissingExtraError

DISTRIBUTION = "cgvq-toolkit"

# Top-level module -> the extra that installs it (the first one that does, by role).
EXTRA_OF_MODULE: dict[str, str] = {
    "torch": "metric",
    "scipy": "analysis",
    "pandas": "analysis",
    "sureal": "analysis",
    "pingouin": "analysis",
    "matplotlib": "analysis",
    "ray": "cluster",
    "uvicorn": "server",
    "starlette": "server",
    "fastapi": "server",
    "jinja2": "server",
    "study_server": "server",  # absent only from the frozen participant app
    "selenium": "dev",
    "flip_evaluator": "metric",
}


def install_hint(extra: str) -> str:
    """The pip command that installs ``extra``."""
    return f"pip install '{DISTRIBUTION}[{extra}]'"


def explain_missing(exc: ModuleNotFoundError, *, what: str,
                    extra: str | None = None) -> MissingExtraError | None:
    """A :class:`MissingExtraError` for an optional module, or None for any other module.

    ``what`` names the command or feature ("cgvq-study synth"); ``extra`` overrides the extra
    looked up from the module name (a command may need scipy through ``[synth]``).
    """
    top = (exc.name or "").split(".")[0]
    if top not in EXTRA_OF_MODULE:
        return None
    chosen = extra or EXTRA_OF_MODULE[top]
    return MissingExtraError(
        f"{what} needs the [{chosen}] extra ({top} is not installed): {install_hint(chosen)}")
