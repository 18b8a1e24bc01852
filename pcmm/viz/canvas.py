"""matplotlib without pyplot's global state: a Figure on its own Agg canvas (every view's figures)."""
from __future__ import annotations

from ..errors import UsageError


def _matplotlib():
    try:
        import matplotlib  # noqa: F401 - only whether it is there
    except ImportError:
        raise UsageError("figures need matplotlib, an optional extra: pip install 'pcmm[plots]'") from None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    def make(**kw):  # the Agg canvas, without pyplot's global state
        fig = Figure(**kw)
        FigureCanvasAgg(fig)
        return fig
    return make
