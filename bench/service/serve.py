"""Real ``signmap`` child processes for the benches (and the browser tests): a free port, the
environment that hands a child its settings, a process group ended with its children, and
``serve`` waiting until /health answers."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import httpx

from app.settings import Settings

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # closed again when the socket is: the child takes it


def child_env(settings: Settings) -> dict[str, str]:
    """The environment that makes a child process's Settings() equal ``settings``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("SIGNMAP_")}
    env.update(settings.as_env())
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


@contextmanager
def signmap_child(argv: list[str], env: dict[str, str], log: Path) -> Iterator[subprocess.Popen]:
    """``signmap argv`` in its own process group, output appended to ``log``; ended (with its
    children: a worker's pool, an embedded job's COLMAP) on exit."""
    with log.open("ab") as out:
        proc = subprocess.Popen([sys.executable, "-m", "app.cli", *argv], cwd=REPO, env=env,
                                stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        yield proc
    finally:
        for sig, wait_s in ((signal.SIGTERM, 30), (signal.SIGKILL, 10)):
            if proc.poll() is not None:
                break
            try:
                os.killpg(proc.pid, sig)
                proc.wait(wait_s)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                pass


def wait_healthy(base_url: str, proc: subprocess.Popen, log: Path, timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"signmap serve exited ({proc.returncode}): "
                               f"{log.read_text()[-2000:]}")
        try:
            if httpx.get(f"{base_url}/api/v1/health", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"signmap serve not healthy after {timeout_s} s: {log.read_text()[-2000:]}")


@contextmanager
def serve(env: dict[str, str], log: Path) -> Iterator[str]:
    """``signmap serve`` on a free port of 127.0.0.1, healthy; yields its base URL."""
    port = free_port()
    with signmap_child(["serve", "--host", "127.0.0.1", "--port", str(port)], env, log) as proc:
        base = f"http://127.0.0.1:{port}"
        wait_healthy(base, proc, log)
        yield base
