"""Screenshots of rerun recordings as a reader sees them: rerun's web viewer in headless Chromium.

`python -m tools.review_shots OUT_DIR [REC.rrd ...]` serves each recording (none given: one of each kind,
made first) with
`rerun --serve-web`, opens the web viewer in headless Chromium (Debian's `chromium` with SwiftShader:
software WebGL, no GPU), waits for the viewer to load and draw, and saves `OUT_DIR/<rrd stem>.png`.

Chromium is driven over its DevTools pipe (`--remote-debugging-pipe`: JSON messages over two file
descriptors), so nothing beyond the standard library is needed, and the page runs `--wait` seconds of real
time: the viewer's WebAssembly compiles and SwiftShader draws in real time, which `--virtual-time-budget`
does not wait for (and over the pipe the page is closed once that budget is spent, so it is not set).
`make review-shots` makes one recording of each kind (sysid-run, sysid-diagnose, sysid-report) and shoots them.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CHROMIUM_FLAGS", "Shot", "chromium_path", "main", "read_png", "screenshot", "shoot"]

CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-extensions",
    "--disable-dev-shm-usage",
)


def chromium_path() -> str | None:
    """The Chromium binary on PATH (`chromium`, `chromium-browser`, `google-chrome`), or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _DevTools:
    """Chromium with its DevTools protocol on a pipe: we write to its fd 3, it writes to its fd 4."""

    def __init__(self, binary: str, width: int, height: int, stderr: Any = subprocess.DEVNULL) -> None:
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        # Chromium reads fd 3 and writes fd 4: hand it the pipe ends at exactly those numbers.
        high_r, high_w = os.dup(to_child_r), os.dup(from_child_w)
        for fd in (to_child_r, from_child_w):
            os.close(fd)

        def place() -> None:
            os.dup2(high_r, 3)
            os.dup2(high_w, 4)

        args = [binary, *CHROMIUM_FLAGS, f"--window-size={width},{height}", "--remote-debugging-pipe"]
        self.proc = subprocess.Popen(
            args,
            preexec_fn=place,
            close_fds=False,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=stderr,
            start_new_session=True,
        )
        os.close(high_r)
        os.close(high_w)
        os.set_inheritable(to_child_w, False)
        os.set_inheritable(from_child_r, False)
        self._write, self._read = to_child_w, from_child_r
        os.set_blocking(self._read, False)
        self._buf = b""
        self._id = 0

    def call(
        self, method: str, params: dict[str, Any] | None = None, *, session: str | None = None, timeout_s: float = 60.0
    ) -> dict[str, Any]:
        """Send one command and wait for its answer (events that arrive meanwhile are dropped)."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session is not None:
            msg["sessionId"] = session
        os.write(self._write, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                answer = json.loads(raw)
                self._event(answer)
                if answer.get("id") == self._id:
                    if "error" in answer:
                        raise RuntimeError(f"chromium: {method}: {answer['error']}")
                    return dict(answer.get("result", {}))
            if time.monotonic() > deadline:
                raise TimeoutError(f"chromium did not answer {method} within {timeout_s:g} s")
            if self.proc.poll() is not None:
                raise RuntimeError(f"chromium exited with status {self.proc.returncode}")
            try:
                chunk = os.read(self._read, 1 << 20)
            except BlockingIOError:
                time.sleep(0.05)
                continue
            if not chunk:
                raise RuntimeError("chromium closed its DevTools pipe")
            self._buf += chunk

    def pump(self, seconds: float) -> None:
        """Let the page run for `seconds` of real time, draining Chromium's events (no command is sent:
        the viewer's main thread is busy drawing in software and would answer late)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                chunk = os.read(self._read, 1 << 20)
            except BlockingIOError:
                time.sleep(0.1)
                continue
            if not chunk:
                raise RuntimeError("chromium closed its DevTools pipe")
            self._buf += chunk
            *messages, self._buf = self._buf.split(b"\0")
            for raw in messages:
                self._event(json.loads(raw))

    def _event(self, message: dict[str, Any]) -> None:
        """Print an event to stderr when REVIEW_SHOTS_DEBUG is set (the renderer's crashes show here)."""
        if os.environ.get("REVIEW_SHOTS_DEBUG") and "method" in message:
            print("event", message["method"], str(message.get("params"))[:300], file=sys.stderr)

    def open(self, url: str) -> None:
        # Open the page at its address: a navigation away from about:blank swaps the renderer process and
        # ends the DevTools session attached to it.
        target = self.call("Target.createTarget", {"url": url})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]

    def png(self) -> bytes:
        data = self.call("Page.captureScreenshot", {"format": "png"}, session=self.session, timeout_s=300.0)
        return base64.b64decode(data["data"])

    def close(self) -> None:
        for fd in (self._write, self._read):
            try:
                os.close(fd)
            except OSError:
                pass
        _stop(self.proc)


@dataclass(frozen=True)
class Shot:
    """One screenshot of one recording.

    Attributes:
        recording: the .rrd shown.
        png: where the screenshot went.
        server_log: what `rerun --serve-web` printed (it names the file it loaded and the viewer's address),
            then Chromium's own messages.
    """

    recording: Path
    png: Path
    server_log: str


def screenshot(
    rrd: Path, png: Path, *, wait_s: float = 45.0, width: int = 1920, height: int = 1080, binary: str | None = None
) -> Shot:
    """Serve `rrd` to rerun's web viewer, render it in headless Chromium for `wait_s` seconds and save `png`.

    Raises:
        FileNotFoundError: no Chromium on PATH, or no `rerun` beside this Python.
    """
    binary = binary or chromium_path()
    if binary is None:
        raise FileNotFoundError("no chromium on PATH (Debian: apt-get install -y chromium)")
    rerun = Path(sys.executable).with_name("rerun")
    if not rerun.is_file():
        found = shutil.which("rerun")
        if found is None:
            raise FileNotFoundError("no `rerun` executable beside this Python or on PATH (pip install rerun-sdk)")
        rerun = Path(found)
    web, grpc = _free_port(), _free_port()
    log_path = png.with_suffix(".server.log")
    png.parent.mkdir(parents=True, exist_ok=True)
    log = log_path.open("w")  # rerun's output, then Chromium's
    server = subprocess.Popen(
        [str(rerun), "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc), str(rrd)],
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        env={**os.environ, "RERUN_ANALYTICS": "0"},
        start_new_session=True,
    )
    try:
        _wait_for_port(web, server, timeout_s=30.0)
        browser = _DevTools(binary, width, height, stderr=log)
        try:
            browser.open(f"http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy&renderer=webgl")
            browser.pump(wait_s)
            png.write_bytes(browser.png())
        finally:
            browser.close()
    finally:
        _stop(server)
        log.close()
    return Shot(recording=Path(rrd), png=png, server_log=log_path.read_text())


def _stop(proc: subprocess.Popen) -> None:
    """End `proc` and every process it started (its own session: Chromium's renderers, rerun's viewer)."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=10)
    except ProcessLookupError:
        return
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _wait_for_port(port: int, proc: subprocess.Popen, *, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(f"rerun --serve-web exited with status {proc.returncode}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise TimeoutError(f"rerun's web viewer did not listen on port {port} within {timeout_s:g} s")


def read_png(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB pixels of a PNG."""
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def shoot(recordings: list[Path], out_dir: Path, *, wait_s: float = 45.0) -> list[Shot]:
    """One screenshot per recording, `out_dir/<stem>.png`."""
    return [screenshot(Path(r), Path(out_dir) / f"{Path(r).stem}.png", wait_s=wait_s) for r in recordings]


def make_recordings(work: Path) -> list[Path]:
    """One recording of each kind into `work`: a two_link sysid-run, a sysid-diagnose (of the DFKI logs where
    ../shared has them, else of the run's data) and the sysid-report of a 2-job sweep. Returns the .rrd paths."""
    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")])}

    def call(*args: str) -> None:
        subprocess.run([sys.executable, "-m", *args], cwd=repo, env=env, check=True, stdout=subprocess.DEVNULL)

    run, diag, sweep = work / "run", work / "diagnose", work / "sweep"
    call("harness.run", "system=two_link", f"hydra.run.dir={run}")
    # the DFKI arm's real logs where ../shared holds them (something to find), else the run's simulated data
    data = (
        ["data=dfki_double_pendulum"] if (repo.parent / "shared" / "data").is_dir() else [f"data.path={run}/data.csv"]
    )
    call("harness.diagnose", "system=two_link", *data, f"hydra.run.dir={diag}")
    call("harness.run", "-m", "system=pendulum,two_link", "record=none", f"hydra.sweep.dir={sweep}")
    call("harness.report", str(sweep))
    return [run / "recording.rrd", diag / "diagnosis.rrd", sweep / "report.rrd"]


def main(argv: list[str] | None = None) -> int:
    """`python -m tools.review_shots OUT_DIR [REC.rrd ...]` (no recordings: make one of each kind first)."""
    parser = argparse.ArgumentParser(prog="review-shots", description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("recordings", type=Path, nargs="*")
    parser.add_argument("--wait", type=float, default=60.0, help="seconds the viewer gets to load and draw")
    args = parser.parse_args(argv)
    try:
        recordings = args.recordings or make_recordings(args.out_dir / "recordings")
        shots = shoot(recordings, args.out_dir, wait_s=args.wait)
    except (FileNotFoundError, TimeoutError, RuntimeError) as err:
        print(f"review-shots: {err}", file=sys.stderr)
        return 2
    for s in shots:
        print(f"{s.recording} -> {s.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
