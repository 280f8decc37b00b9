"""`sysid-report <sweep dir>`: one table (markdown and CSV) and one recording comparing the runs of a sweep.

Each job folder of a Hydra multirun holds `results.json` (sysid-run), `diagnosis.json` (sysid-diagnose) or
`failure.json` (a job that raised: the sweep went on without it). Written into the sweep folder:
`report.md`, `report.csv` and `report.rrd`, each whole or not at all, with `.sysid_report.json` noting what was
written (`OUTPUTS`). Run again, sysid-report replaces its own report; a file of those names it did not write, or
one changed since it wrote it (a user's notes in report.md), is never replaced: the run is refused, naming it.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from envs.dataset import atomic_write
from harness.rundir import STAGING_PREFIX, failed_since_results

__all__ = ["ForeignReportError", "check_outputs", "collect", "main", "report_rows", "write_report"]


def _overrides(job: Path) -> str:
    path = job / ".hydra" / "overrides.yaml"
    if not path.is_file():
        return ""
    lines = [ln.strip()[2:] for ln in path.read_text().splitlines() if ln.strip().startswith("- ")]
    return " ".join(lines)


def collect(sweep: Path) -> list[dict[str, Any]]:
    """One record per job folder (any folder below `sweep` holding a `.hydra` folder or an output file)."""
    sweep = Path(sweep)
    if sweep.is_file():
        raise FileNotFoundError(f"{sweep} is a file, not a sweep folder: give the folder of the sweep (or one run)")
    if not sweep.is_dir():
        raise FileNotFoundError(f"sweep folder not found: {sweep}")

    def found(name: str) -> set[Path]:  # not inside a run's staging folder (`harness.rundir.STAGING_PREFIX`)
        return {p.parent for p in sweep.rglob(name) if not any(x.startswith(STAGING_PREFIX) for x in p.parts)}

    jobs = sorted(found(".hydra") | found("results.json"))
    jobs += sorted(found("diagnosis.json") - set(jobs))
    # a sweep re-run into its folder (overwrite=true) with fewer jobs leaves the earlier sweep's other jobs:
    # Hydra writes multirun.yaml as a sweep starts and each job's .hydra/ after it
    start = (sweep / "multirun.yaml").stat().st_mtime if (sweep / "multirun.yaml").is_file() else None
    swept = _swept_values(sweep / "multirun.yaml") if start is not None else {}
    out = []
    for job in sorted(set(jobs)):
        record: dict[str, Any] = {"job": str(job.relative_to(sweep)) or ".", "overrides": _overrides(job)}
        written = [f.stat().st_mtime for f in (job / ".hydra").glob("*.yaml")]  # rewritten in place by a new job
        older = start is not None and bool(written) and max(written) < start - STALE_S
        if older and _outside(record["overrides"], swept):  # both: a copied folder's times say nothing
            out.append({**record, "kind": "?", "status": "stale", "error": STALE})
            continue
        for name, kind in (("results.json", "run"), ("diagnosis.json", "diagnose")):
            if (job / name).is_file() and not failed_since_results(job):
                try:
                    payload = _read_json(job / name)
                except ValueError as err:
                    record.update(kind=kind, status="failed", error=str(err))
                    break
                if isinstance(payload.get("overrides"), list):  # the run's own, whatever .hydra/ says now
                    record["overrides"] = " ".join(str(o) for o in payload["overrides"])
                record.update(kind=kind, status="ok", payload=payload)
                break
        else:
            record.update(kind="?", status="failed", error=_failure(job))
        out.append(record)
    if not out:
        raise FileNotFoundError(f"{sweep}: no job folders (with .hydra/, results.json or diagnosis.json) below it")
    return out


STALE_S = 1.0  # [s] a job folder's .hydra/ this much older than the sweep's multirun.yaml is an earlier sweep's
STALE = "an earlier sweep's job (its .hydra/ is older than this sweep's multirun.yaml): not counted"


def _swept_values(multirun: Path) -> dict[str, set[str] | None]:
    """Per key of the sweep's command line (multirun.yaml's hydra.overrides.task): the values it sweeps, None
    where they are not a plain comma list (range(), glob(), ...: any value counts as the sweep's)."""
    try:
        task = OmegaConf.load(multirun).hydra.overrides.task
    except (OSError, ValueError, KeyError, AttributeError, OmegaConfBaseException, yaml.YAMLError):
        # an unreadable or foreign multirun.yaml: nothing to tell earlier jobs by
        return {}
    out: dict[str, set[str] | None] = {}
    for item in task:
        key, _, value = str(item).partition("=")
        plain = "(" not in value and "[" not in value and "{" not in value
        out[key] = {v.strip() for v in value.split(",")} if plain else None
    return out


def _outside(overrides: str, swept: dict[str, set[str] | None]) -> bool:
    """Whether a job's overrides ("k=v k=v") hold a value of a swept key that the sweep does not sweep, or a key
    the sweep does not set: a job of another command line."""
    for item in overrides.split():
        key, _, value = item.partition("=")
        if key not in swept:
            return True
        values = swept[key]
        if values is not None and value not in values:
            return True
    return False


def _read_json(path: Path) -> dict[str, Any]:
    """A job file's JSON object; ValueError naming the file when it is unreadable, corrupt or not an object."""
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: unreadable or corrupt ({type(err).__name__}: {err})") from None
    if not isinstance(payload, dict):
        raise ValueError(f"{path}: corrupt (a JSON {type(payload).__name__}, not an object)")
    return payload


def _failure(job: Path) -> str:
    failure = job / "failure.json"
    if not failure.is_file():
        return "no output (still running, or killed before it could record why)"
    try:
        return str(_read_json(failure)["error"])
    except (ValueError, KeyError) as err:
        return f"failed; its failure.json is unreadable: {err}"


def report_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Flat rows: the job, its overrides and status, and the headline numbers of its output."""
    rows = []
    for r in records:
        row: dict[str, Any] = {"job": r["job"], "overrides": r["overrides"], "status": r["status"]}
        p: dict[str, Any] = r.get("payload") or {}
        if r["status"] != "ok":
            row["error"] = r["error"]
            rows.append(row)
            continue
        file = "results.json" if r["kind"] == "run" else "diagnosis.json"
        try:
            row.update(_headline(r["kind"], p))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            row.update(status="failed", error=f"{r['job']}/{file}: incomplete or corrupt ({type(err).__name__}: {err})")
        # the tools write strict JSON (no NaN): a non-finite number is a file edited or written by something else
        bad = [k for k, v in row.items() if isinstance(v, float) and not math.isfinite(v)]
        if bad and row["status"] == "ok":
            row.update(status="failed", error=f"{r['job']}/{file}: {bad[0]} is {row[bad[0]]}, not a finite number")
        rows.append(row)
    return rows


def _headline(kind: str, p: dict[str, Any]) -> dict[str, Any]:
    """The headline numbers of one job's output."""
    row: dict[str, Any] = {}
    if kind == "run":
        row.update(
            system=p["system"],
            estimator=p.get("estimator"),
            excitation=p["excitation"]["name"],
            harmonics=p["excitation"]["harmonics"],
            cond_XtX=p["excitation"]["cond_XtX"],
            cond_W_colnorm=p["excitation"]["cond_W_colnorm"],
            limits_ok=p["excitation"]["limits_ok"],
            # None where no estimate has a std (the gradient estimator gives none): no |z| to report
            max_abs_z=max((abs(b["z"]) for b in p["base_parameters"] if b.get("z") is not None), default=None),
            **{f"val_rms_{j}": v for j, v in p["validation"]["torque_rms"].items()},
            time_s=sum(p["timing_s"].values()),
        )
    else:
        findings = p.get("findings", [])
        row.update(
            system=p["system"],
            verdict=p["verdict"],
            first_finding=findings[0]["effect"] if findings else "",
            **{f"baseline_rms_{j}": v for j, v in p["baseline"]["torque_rms"].items()},
            **{f"extended_rms_{j}": v for j, v in p.get("extended", {}).get("torque_rms", {}).items()},
        )
    return row


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)


OUTPUTS = ("report.md", "report.csv", "report.rrd")
MANIFEST = ".sysid_report.json"  # {output name: [sha256 of each version sysid-report may have left in place]}
_JOBS_LINE = re.compile(r"\d+ jobs, \d+ ok, \d+ failed")
_RRD_MAGIC = b"RRF"  # what every rerun recording file starts with


class ForeignReportError(FileExistsError):
    """A file where the report goes that sysid-report did not write, or that changed since it did."""


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _manifest(sweep: Path) -> dict[str, list[str]] | None:
    """The manifest's accepted digests per output; None where there is none; ForeignReportError where one is
    there that cannot be read as sysid-report writes it (it guards the user's files: it is not guessed past)."""
    path = sweep / MANIFEST
    if not path.exists() and not path.is_symlink():
        return None
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise ValueError("not an object")
        return {k: [v] if isinstance(v, str) else [d for d in v if isinstance(d, str)] for k, v in data.items()}
    except (OSError, ValueError, TypeError, UnicodeDecodeError) as err:
        raise ForeignReportError(
            f"{path} cannot be read ({err}): it says which report files sysid-report wrote, so none is written "
            "over; move the report files you want to keep away, delete it, and run sysid-report again"
        ) from err


def _earlier_version(name: str, data: bytes) -> bool:
    """Whether `data` is the file `name` as sysid-report wrote it before the manifest existed: a report.md that
    is its table and ends with the jobs line (then, if any, the left-out line), a report.csv whose header starts
    with job, overrides, status, a rerun recording."""
    if name == "report.rrd":
        return data.startswith(_RRD_MAGIC)
    try:
        text = data.decode()
    except UnicodeDecodeError:
        return False
    if name == "report.csv":
        return text.startswith("job,overrides,status")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if lines and lines[-1].startswith("Left out, from an earlier sweep in this folder: "):
        lines = lines[:-1]
    return bool(lines) and lines[0].startswith("| ") and bool(_JOBS_LINE.fullmatch(lines[-1]))


def check_outputs(sweep: Path) -> dict[str, str]:
    """The digest of each of `OUTPUTS` in `sweep` that is sysid-report's (as the manifest notes it, or, in a
    folder without one, as `_earlier_version` recognises it); ForeignReportError naming the first that is
    not, or a manifest that cannot be read."""
    accepted = _manifest(sweep)
    ours: dict[str, str] = {}
    for name in OUTPUTS:
        path = sweep / name
        if not path.exists() and not path.is_symlink():
            continue
        data = path.read_bytes() if path.is_file() and not path.is_symlink() else None
        if data is not None:
            digest = _digest(data)
            if digest in (accepted or {}).get(name, []) or (accepted is None and _earlier_version(name, data)):
                ours[name] = digest
                continue
        raise ForeignReportError(
            f"{path} was not written by sysid-report, or was changed since: nothing is written over it; move it "
            "away (or delete it) and run sysid-report again"
        )
    return ours


def _write_manifest(sweep: Path, accepted: dict[str, list[str]]) -> None:
    atomic_write(sweep / MANIFEST, lambda f: f.write(json.dumps(accepted, indent=1) + "\n"))


def write_report(sweep: Path, rows: list[dict[str, Any]], records: list[dict[str, Any]] | None = None) -> None:
    """report.md, report.csv and report.rrd in the sweep folder, each written whole or not at all; none of them
    where one in the folder is not sysid-report's (`check_outputs`: ForeignReportError).

    All three are made first, in memory. The manifest then accepts both the old
    and the new version of each before any is put in place, and only the new ones after: a run cut short at any
    point leaves files the next run recognises as its own. Two runs at once on one folder are not guarded."""
    sweep = Path(sweep)
    ours = check_outputs(sweep)
    stale = [r["job"] for r in rows if r["status"] == "stale"]
    rows = [r for r in rows if r["status"] != "stale"]
    records = None if records is None else [r for r in records if r["status"] != "stale"]
    columns = list(dict.fromkeys(k for row in rows for k in row))
    md = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    md += ["| " + " | ".join(_fmt(row.get(c)) for c in columns) + " |" for row in rows]
    n_failed = sum(r["status"] != "ok" for r in rows)
    md += ["", f"{len(rows)} jobs, {len(rows) - n_failed} ok, {n_failed} failed"]
    if stale:
        md += ["", f"Left out, from an earlier sweep in this folder: {', '.join(stale)}"]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    made = {
        "report.md": ("\n".join(md) + "\n").encode(),
        "report.csv": buf.getvalue().encode(),
        "report.rrd": _recording(rows, records),
    }
    new = {name: _digest(data) for name, data in made.items()}
    _write_manifest(sweep, {name: [*([ours[name]] if name in ours else []), new[name]] for name in OUTPUTS})
    for name, data in made.items():
        atomic_write(sweep / name, lambda f, data=data: f.write(data), binary=True)
    _write_manifest(sweep, {name: [new[name]] for name in OUTPUTS})


# Reference lines drawn on the report's charts: the largest |z| a calibrated std allows about once in 370
# parameters, and the validation RMS a right model reaches within 20 % of the sensor noise.
THRESHOLDS = {"max_abs_z": 3.0, "val_rms_over_noise": 1.2}


def _normalised_rms(record: dict[str, Any]) -> dict[str, float]:
    """Validation torque RMS / sensor noise std per measured joint of a sysid-run job (none for others)."""
    p = record.get("payload") or {}
    if record.get("status") != "ok" or record.get("kind") != "run":
        return {}
    validation = p.get("validation") if isinstance(p, dict) else None
    if not isinstance(validation, dict):  # a job file without it (written by hand, or cut short) shows no bar
        return {}
    rms, noise = validation.get("torque_rms") or {}, validation.get("noise_std") or {}
    return {j: float(rms[j]) / float(noise[j]) for j in rms if noise.get(j)}


def _recording(rows: list[dict[str, Any]], records: list[dict[str, Any]] | None = None) -> bytes:
    """report.rrd's bytes: one bar chart per headline number, one bar (named in the legend) per job, thresholds
    drawn."""
    import rerun as rr
    import rerun.blueprint as rrb

    from harness.record import ROLE_COLORS, recording_bytes

    ok = [r for r in rows if r["status"] == "ok"]
    numeric = [c for c in dict.fromkeys(k for r in ok for k in r) if all(isinstance(r.get(c), float) for r in ok)]
    normalised = {r["job"]: _normalised_rms(r) for r in (records or [])}
    per_job = {c: [(r["job"], float(r[c])) for r in ok] for c in numeric if not c.startswith("val_rms_")}
    charts: dict[str, list[tuple[str, float]]] = {}
    if "max_abs_z" in per_job:  # the key metrics first
        charts["max_abs_z"] = per_job.pop("max_abs_z")
    if any(normalised.values()):
        charts["val_rms_over_noise"] = [
            (f"{job}_{joint}", value) for job, per_joint in normalised.items() for joint, value in per_joint.items()
        ]
    charts |= per_job
    titles = {
        "max_abs_z": "max |z| over base parameters [1]",
        "val_rms_over_noise": "validation torque RMS / sensor noise std, per joint [1]",
        "cond_XtX": "cond(XᵀX) [1]",
        "cond_W_colnorm": "cond(W), column-normalised [1]",
        "time_s": "wall time [s]",
    }
    palette = [(86, 180, 233), (230, 159, 0), (0, 158, 115), (240, 228, 66), (0, 114, 178), (213, 94, 0)]

    def fill(rec: rr.RecordingStream) -> None:
        views = [
            rrb.BarChartView(
                origin=f"/runs/{c}",
                name=titles.get(c, _title(c)),
                plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True),
            )
            for c in charts
        ]
        table = rrb.TextDocumentView(origin="/runs/table", name="jobs")
        rec.send_blueprint(rrb.Blueprint(rrb.Grid(*views, table), collapse_panels=True))
        for c, bars in charts.items():
            jobs = [r["job"] for r in ok]
            threshold = THRESHOLDS.get(c)
            if threshold is not None:
                rec.log(
                    f"runs/{c}/threshold_{threshold:g}",
                    rr.BarChart(
                        [threshold],
                        abscissa=[-0.15],  # rerun draws a bar from its abscissa to abscissa + width
                        widths=[float(len(bars))],
                        color=(*ROLE_COLORS["reference"], 70),
                    ),
                    static=True,
                )
            for i, (label, value) in enumerate(bars):
                owner = next((k for k, job in enumerate(jobs) if label == job or label.startswith(f"{job}_")), 0)
                color = palette[owner % len(palette)]
                rec.log(
                    f"runs/{c}/{rr.escape_entity_path_part(label)}",
                    rr.BarChart([value], abscissa=[float(i)], widths=[0.7], color=color),
                    static=True,
                )
        legend = "\n".join(f"- `{r['job']}`: {r['overrides'] or '(defaults)'}" for r in ok)
        failed = "\n".join(f"- `{r['job']}` {r['overrides']}: {r['error']}" for r in rows if r["status"] != "ok")
        marks = ", ".join(f"{k} = {v:g}" for k, v in THRESHOLDS.items())
        text = (
            f"**{len(rows)} jobs, {len(ok)} ok, {len(rows) - len(ok)} failed.** Each bar is one job, named in "
            f"the chart's legend; shaded: the threshold ({marks}).\n\nJobs:\n\n{legend}\n\n"
            f"Failed:\n\n{failed or '(none)'}"
        )
        rec.log("runs/table", rr.TextDocument(text, media_type="text/markdown"), static=True)

    return recording_bytes("sysid-report", fill)


def _title(column: str) -> str:
    unit = " [N m]" if "rms" in column else ""
    return column.replace("_", " ") + unit


def main(argv: list[str] | None = None) -> int:
    """Console entry point `sysid-report <sweep dir>`: 0 when every job finished, 1 when any failed (the report
    lists them and is written either way), 2 when no report could be made."""
    parser = argparse.ArgumentParser(prog="sysid-report", description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="a Hydra multirun folder, e.g. multirun/2026-11-23_12-00-00")
    args = parser.parse_args(argv)
    try:
        records = collect(args.sweep)
        rows = report_rows(records)
    except FileNotFoundError as err:
        print(f"sysid-report: {err}", file=sys.stderr)
        return 2
    try:
        write_report(args.sweep, rows, records)
    except ForeignReportError as err:
        print(f"sysid-report: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"sysid-report: error: cannot write the report into {args.sweep}: {err.strerror or err}", file=sys.stderr)
        return 2
    print((args.sweep / "report.md").read_text())
    failed = [row for row in rows if row["status"] not in ("ok", "stale")]
    for row in failed:
        print(f"sysid-report: job {row['job']} failed: {row['error']}", file=sys.stderr)
    return 1 if failed else 0  # the report is written either way; a script sees that jobs failed


if __name__ == "__main__":
    sys.exit(main())
