"""matplotlib, imported on first use, headless (Agg), or a one-line error naming the extra."""
from __future__ import annotations

from ..errors import UserError, install_hint


def missing(flag: str) -> UserError:
    """The one-line error of a ``flag`` that needs the plots extra."""
    return UserError(f"{flag} needs matplotlib, the plots extra: {install_hint('plots')}")


def require(flag: str) -> None:
    """The plots extra present (found, not imported: the CLI checks it before any work)."""
    import importlib.util
    if importlib.util.find_spec("matplotlib") is None:
        raise missing(flag)


def pyplot(flag: str):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise missing(flag) from None
    return plt


def save(fig, path: str, flag: str) -> str:
    from ..errors import CannotCreate
    plt = pyplot(flag)
    try:
        # no timestamp in the file, so a regenerated picture differs only when its content does
        fig.savefig(path, dpi=90, metadata={"Software": None} if path.endswith(".png") else
                    {"Date": None} if path.endswith(".svg") else None)
    except OSError as e:
        raise CannotCreate(f"{flag} {path}: cannot write: {e.strerror}") from None
    finally:
        plt.close(fig)
    return path
