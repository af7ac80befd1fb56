"""Map tiles under plots in the local metric frame (the paper overlays Google Maps, Figure 11).

pykitti's local frame is Web Mercator (EPSG:3857) scaled by ``s = cos(lat0)`` and shifted to the first
OXTS packet: ``local = s * X_3857 - origin``. So tiles fetched in EPSG:3857 (contextily) are placed in
the local frame by an affine map, without resampling.

``source`` is an xyzservices provider name (``OpenStreetMap.Mapnik``, ``Esri.WorldImagery``) or a
``{z}/{x}/{y}`` URL template (e.g. Google's, where its terms allow). Fetched tiles are cached on disk.
When tiles cannot be had, the plot goes on without them and a warning says why.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.geo import GeoFrame, latlon_to_mercator


class BasemapWarning(UserWarning):
    """The basemap could not be drawn; the plot continues without it."""


@dataclass(frozen=True)
class Tiles:
    """Where map tiles come from: an xyzservices name or ``{z}/{x}/{y}`` URL, an on-disk cache, a timeout."""

    source: str = "OpenStreetMap.Mapnik"
    cache_dir: str | None = "~/.cache/featmap/tiles"
    timeout_s: float = 5.0


def tile_provider(source: str):
    """The xyzservices provider named ``source`` (``"OpenStreetMap.Mapnik"``), or ``source`` itself when it is a
    ``{z}/{x}/{y}`` URL template. Raises ValueError for an unknown name."""
    import xyzservices.providers as xyz

    if "{" in source:
        return source
    node = xyz
    for part in source.split("."):
        node = node[part] if part in node else None
        if node is None:
            raise ValueError(f"unknown tile source {source!r}: an xyzservices name such as OpenStreetMap.Mapnik, "
                             "or a URL template with {z}/{x}/{y}")
    return node


def add_basemap(ax, frame: GeoFrame, tiles: Tiles = Tiles(), zoom: int | str = "auto", attribution: bool = True) -> bool:
    """Draw tiles under the current view of ``ax`` (local frame). Returns False (and warns) on failure."""
    import contextily as ctx

    source, cache_dir, timeout_s = tiles.source, tiles.cache_dir, tiles.timeout_s

    x0, x1 = sorted(ax.get_xlim())
    y0, y1 = sorted(ax.get_ylim())
    s = frame.scale
    ox, oy = latlon_to_mercator(frame.lat0_deg, frame.lon0_deg, s)
    # local -> EPSG:3857: X = (x + ox) / s
    w, e = (x0 + ox) / s, (x1 + ox) / s
    south, north = (y0 + oy) / s, (y1 + oy) / s
    try:
        provider = tile_provider(source)
        if zoom == "auto":
            max_zoom = int(getattr(provider, "max_zoom", 19) or 19)
            zoom = int(np.clip(np.round(np.log2(40075016.0 * 3 / max(e - w, 1.0))), 0, max_zoom))
        if cache_dir is not None:
            Path(cache_dir).expanduser().mkdir(parents=True, exist_ok=True)
            ctx.set_cache_dir(str(Path(cache_dir).expanduser()))
        img, ext = ctx.bounds2img(w, south, e, north, zoom=zoom, source=provider, ll=False, max_retries=0,
                                  timeout=timeout_s, use_cache=cache_dir is not None)
    except Exception as exc:  # network, HTTP, decoding: a basemap is never worth failing a plot for
        warnings.warn(f"basemap unavailable ({type(exc).__name__}: {_short(exc)}); plotting without tiles",
                      BasemapWarning, stacklevel=2)
        return False
    left, right, bottom, top = ext
    extent = (left * s - ox, right * s - ox, bottom * s - oy, top * s - oy)
    ax.imshow(img, extent=extent, zorder=0, interpolation="bilinear")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    if attribution:
        text = getattr(provider, "attribution", None) or (f"tiles: {source}" if isinstance(provider, str) else "")
        if text:
            ax.text(0.99, 0.01, text[:90], transform=ax.transAxes, ha="right", va="bottom", fontsize=6,
                    bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none", "pad": 1})
    return True


def _short(exc: Exception, limit: int = 140) -> str:
    """The gist of an exception's message: without a "(Caused by ...)" tail, cut at a word within ``limit``."""
    text = " ".join(str(exc).split(" (Caused by")[0].split())
    if len(text) <= limit:
        return text
    return text[:limit].rsplit(" ", 1)[0] + " ..."
