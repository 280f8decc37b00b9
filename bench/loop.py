"""The end-to-end loop per system: conditioning, largest |z|, validation RMS against noise, time per stage.

Writes bench/loop.json and bench/loop.md. Re-run: `make bench` or `.venv/bin/python -m bench loop`.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from hydra import compose, initialize_config_dir

from dynamics.plant import MJCF_DIR
from harness.run import run
from harness.setup import CONF_DIR

HERE = Path(__file__).resolve().parent
SYSTEMS = ("pendulum", "two_link", "wheel_pendulum", "arm3")


def main() -> None:
    rows = []
    for system in SYSTEMS:
        if not (MJCF_DIR / f"{system}.xml").is_file() or not (CONF_DIR / "system" / f"{system}.yaml").is_file():
            continue
        with initialize_config_dir(str(CONF_DIR), version_base=None):
            cfg = compose("config", [f"system={system}", "record=none"])
        with tempfile.TemporaryDirectory() as tmp:
            r = run(cfg, output_dir=Path(tmp))
        rows.append(
            {
                "system": system,
                "excitation": r["excitation"]["name"],
                "cond_XtX": r["excitation"]["cond_XtX"],
                "cond_W_colnorm": r["excitation"]["cond_W_colnorm"],
                "limits_ok": r["excitation"]["limits_ok"],
                "max_abs_z": r["max_abs_z"],
                "validation_torque_rms": r["validation"]["torque_rms"],
                "noise_std": r["validation"]["noise_std"],
                "timing_s": r["timing_s"],
            }
        )
    (HERE / "loop.json").write_text(json.dumps(rows, indent=2) + "\n")
    lines = [
        "| system | excitation | cond(XᵀX) | cond col-norm | limits | max abs z "
        "| validation RMS / noise std [N m] | time per stage [s] |",
        "|---|---|---:|---:|---|---:|---|---|",
    ]
    for r in rows:
        val = ", ".join(f"{j} {rms:.4g} / {r['noise_std'][j]:.4g}" for j, rms in r["validation_torque_rms"].items())
        timing = ", ".join(f"{k} {v:.2f}" for k, v in r["timing_s"].items())
        lines.append(
            f"| {r['system']} | {r['excitation']} | {r['cond_XtX']:.4g} | {r['cond_W_colnorm']:.3g} | "
            f"{'hold' if r['limits_ok'] else 'BROKEN'} | {r['max_abs_z']:.2f} | {val} | {timing} |"
        )
    (HERE / "loop.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
