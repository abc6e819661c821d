"""PhysDrape: drape a 3-D garment onto a human body of any shape and pose.

One network pass plus a few explicit physics steps (the PhysDrape paper), on a free body model.
Conventions (see DESIGN.md): SI units, world frame y-up, metres; the dtype follows the input.
"""

__version__ = "0.1.0"


def __getattr__(name: str):
    """Lazy re-exports of the public API (`physdrape.drape`, `physdrape.Draper`), so that
    `import physdrape` stays cheap."""
    if name in ("drape", "Draper", "DrapeResult"):
        from physdrape import api

        return getattr(api, name)
    raise AttributeError(f"module 'physdrape' has no attribute {name!r}")
