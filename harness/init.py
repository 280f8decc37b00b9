"""`sysid-init <model> [--out <dir>/system/<name>.yaml]`: a system config for a model, every key explained.

The values are what `sysid-run system.mjcf=<model>` would assume (see `harness.defaults`), written out for
the user to edit. Keep it outside the repository and point the harness at its folder:

    sysid-init robots/arm.xml --out ~/sysid-conf/system/arm.yaml
    sysid-run --config-dir ~/sysid-conf system=arm          # or: hydra.searchpath=[file://$HOME/sysid-conf]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import sys
from pathlib import Path

from omegaconf import OmegaConf

from dynamics.errors import SysIdError
from dynamics.plant import load_plant
from harness.defaults import resolve_system
from harness.setup import CONF_DIR
from harness.validate import check_driven

__all__ = ["main", "system_config_text"]


_PLAIN = re.compile(r"[A-Za-z_/~][A-Za-z0-9_./~+-]*")  # a string YAML reads back as itself, unquoted (not .5)


def _value(value: object) -> str:
    """`value` as YAML text that reads back as it is: a string that YAML would read otherwise (a path with a
    colon, a `#` that starts a comment, a space, `true`, a number) in double quotes."""
    if value is None:
        return "null"
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        keyword = value.lower() in {"true", "false", "yes", "no", "on", "off", "null", "~"}
        return value if _PLAIN.fullmatch(value) and not keyword else json.dumps(value, ensure_ascii=False)
    return str(value)


def system_config_text(model: Path, system: str | None = None) -> str:
    """The YAML text: the auto config's comments, each null replaced by the model's value. `system`: the name
    the config is chosen by (its file's stem; default the model's)."""
    plant = load_plant(model)
    check_driven(plant)  # the config would name a model sysid-run then refuses
    auto = OmegaConf.load(CONF_DIR / "system" / "auto.yaml")
    auto.mjcf = str(model.resolve())
    resolved = OmegaConf.create(OmegaConf.to_container(resolve_system(auto, plant)[0], resolve=True))  # type: ignore[arg-type]
    lines = [
        f"# System config for {model.name}, written by sysid-init from the model (edit any value).",
        f"# Use it with: sysid-run --config-dir <the folder above system/> system={system or plant.name}",
    ]
    prefix: list[str] = []
    for line in (CONF_DIR / "system" / "auto.yaml").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        body, _, comment = line.strip().partition("#")
        if ":" not in body:  # a comment continuing on its own line
            lines.append(line)
            continue
        key, _, raw = body.partition(":")
        prefix = [*prefix[: indent // 2], key.strip()]
        if not raw.strip():
            lines.append(line)
            continue
        value = OmegaConf.select(resolved, ".".join(prefix))
        value = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
        text = f"{' ' * indent}{key.strip()}: {_value(value)}"
        lines.append(f"{text:<30} # {comment.strip()}" if comment else text)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Console entry point `sysid-init`."""
    parser = argparse.ArgumentParser(prog="sysid-init", description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path, help="an MJCF (.xml) or URDF (.urdf) file")
    parser.add_argument("--out", type=Path, help="where to write it (default: print it)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    args = parser.parse_args(argv)
    if args.out is not None and args.out.suffix != ".yaml" and not args.out.is_dir():  # Hydra finds .yaml alone
        print(
            f"sysid-init: error: --out {args.out}: Hydra reads a system config from a .yaml file "
            f"(<dir>/system/<name>.yaml); name it {args.out.with_suffix('.yaml').name}",
            file=sys.stderr,
        )
        return 2
    try:
        text = system_config_text(args.model, None if args.out is None else args.out.stem)
    except (SysIdError, ValueError) as err:
        print(f"sysid-init: error: {err}", file=sys.stderr)
        return 2
    if args.out is None:
        print(text, end="")
        return 0
    if args.out.is_dir():
        print(f"sysid-init: error: --out {args.out} is a folder; give the file to write", file=sys.stderr)
        return 2
    if args.out.exists() and not args.force:
        print(f"sysid-init: error: {args.out} exists; pass --force to overwrite it", file=sys.stderr)
        return 2
    tmp = args.out.with_name(f".{args.out.name}.tmp")
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text)
        tmp.replace(args.out)
    except OSError as err:  # a parent that is a file, no permission: nothing half-written is left
        with contextlib.suppress(OSError):  # none to remove where the parent is a file
            tmp.unlink(missing_ok=True)
        print(f"sysid-init: error: cannot write --out {args.out}: {err.strerror or err}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
