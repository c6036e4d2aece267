"""The built-in bench and experiment configurations (TOML files beside this module)."""

from __future__ import annotations

from pathlib import Path

CONFIG_DIR = Path(__file__).resolve().parent


def path(name: str) -> Path:
    """Return the path of the built-in config ``name`` (with or without ``.toml``)."""
    file = CONFIG_DIR / (name if name.endswith(".toml") else name + ".toml")
    if not file.is_file():
        available = ", ".join(sorted(p.stem for p in CONFIG_DIR.glob("*.toml")))
        raise FileNotFoundError(f"no built-in config {name!r}; available: {available}")
    return file
