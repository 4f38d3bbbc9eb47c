"""The files a map comes with: map_server YAML + PGM, a PNG preview and map.json."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["write_map_outputs"]


def write_map_outputs(
    grid: Any, out_dir: Path, *, mode: str = "trinary", extra: dict[str, Any] | None = None
) -> list[Path]:
    """Write ``map.yaml`` + ``map.pgm``, a ``preview.png`` picture and ``map.json`` (size, sharpness, stats).

    The grid is cropped to what was observed first. Every file is written atomically.
    """
    from slam2d.eval.map_metrics import wall_thickness
    from slam2d.io.atomic import write_json_atomic
    from slam2d.io.map_server import save_grid
    from slam2d.report.images import save_map_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cropped = grid.crop_to_observed()
    yaml_path, pgm_path = save_grid(cropped, out_dir / "map.yaml", mode=mode, crop=False)
    png_path = save_map_png(cropped, out_dir / "preview.png")
    info = {
        "resolution_m": cropped.resolution,
        "size_cells": list(cropped.shape),
        "origin": [float(v) for v in cropped.origin],
        "wall_thickness_cells": wall_thickness(cropped.occupancy()),
        **(extra or {}),
    }
    json_path = out_dir / "map.json"
    write_json_atomic(json_path, info)
    return [yaml_path, pgm_path, png_path, json_path]
