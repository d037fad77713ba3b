"""scripts/*.sh as a new user meets them (issue 13, "first hour of a new user"): any Python >= 3.11
is found (or the script says which it needs), a .venv of an older Python is recreated, run.sh ends
by saying how to put `signmap` on the PATH, and demo.sh checks for curl and jq first.

Fast and harmless: each script runs from a copy in a temporary directory, against fake
interpreters (shell scripts that report a version and log what they are asked to do), with a
PATH holding only those fakes and the few tools the scripts use."""

from __future__ import annotations

import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from tests.utils.paths import REPO

BASH = shutil.which("bash")
TOOLS = ("dirname", "cat", "mkdir", "cp", "mktemp")  # what the scripts call besides Python


def _executable(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    return path


def fake_python(path: Path, version: str, log: Path, venv_bin: Path | None = None) -> Path:
    """An interpreter that reports ``version`` to `-c`, logs every other call, and makes a venv
    (whose python reports the same version, plus the files of ``venv_bin``) for
    `-m venv [--clear] DIR`."""
    extras = f'cp {venv_bin}/* "$dir/bin/"' if venv_bin else ":"
    return _executable(path, f"""#!/bin/sh
if [ "$1" = -c ]; then echo {version}; exit 0; fi
echo "$(basename "$0") $*" >> {log}
if [ "$1 $2" = "-m venv" ]; then
  for dir; do :; done
  mkdir -p "$dir/bin" && cp "$0" "$dir/bin/python" && {extras}
fi
exit 0
""")


@pytest.fixture
def sandbox(tmp_path):
    """A copy of scripts/ in tmp/repo, a bin/ directory for fakes and a call log."""
    repo = tmp_path / "repo"
    shutil.copytree(REPO / "scripts", repo / "scripts")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in TOOLS + ("basename",):
        (bin_dir / tool).symlink_to(shutil.which(tool))
    log = tmp_path / "calls.log"
    log.touch()
    return repo, bin_dir, log


def _bash(repo: Path, bin_dir: Path, argv: list[str], env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([BASH, *argv], cwd=repo, capture_output=True, text=True, timeout=60,
                          env={"PATH": str(bin_dir), "HOME": str(repo), **env})


def run(repo: Path, bin_dir: Path, command: str, **env: str) -> subprocess.CompletedProcess:
    """``bash -c command`` in the sandbox."""
    return _bash(repo, bin_dir, ["-c", command], env)


def script(repo: Path, bin_dir: Path, name: str, *args: str,
           **env: str) -> subprocess.CompletedProcess:
    """``bash scripts/NAME args...`` in the sandbox."""
    return _bash(repo, bin_dir, [f"scripts/{name}", *args], env)


def find_python(repo, bin_dir, **env):
    return run(repo, bin_dir, "source scripts/venv.sh && find_python", **env)


@pytest.mark.parametrize("script", ["run.sh", "test.sh", "demo.sh", "venv.sh"])
def test_scripts_parse_and_do_not_name_one_python(script):
    text = (REPO / "scripts" / script).read_text()
    subprocess.run([BASH, "-n", str(REPO / "scripts" / script)], check=True)
    assert "python3.11}" not in text and "PYTHON:-python3" not in text


def test_the_newest_python_at_least_3_11_is_found(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3", "3.10", log)
    fake_python(bin_dir / "python3.11", "3.11", log)
    fake_python(bin_dir / "python3.12", "3.12", log)
    out = find_python(repo, bin_dir)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(bin_dir / "python3.12")


def test_plain_python3_is_used_when_new_enough(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3", "3.13", log)
    out = find_python(repo, bin_dir)
    assert out.stdout.strip() == str(bin_dir / "python3"), out.stderr


def test_no_python_new_enough_says_what_is_needed(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3", "3.10", log)
    out = find_python(repo, bin_dir)
    assert out.returncode == 1 and out.stdout == ""
    assert "Signmap needs Python 3.11 or newer" in out.stderr
    assert "found only python3 (3.10)" in out.stderr
    assert "PYTHON=/path/to/python3.12 bash" in out.stderr


def test_python_env_is_honoured_and_checked(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3.12", "3.12", log)
    mine = fake_python(repo.parent / "opt" / "mypython", "3.13", log)
    out = find_python(repo, bin_dir, PYTHON=str(mine))
    assert out.stdout.strip() == str(mine), out.stderr
    old = fake_python(repo.parent / "opt" / "oldpython", "3.9", log)
    out = find_python(repo, bin_dir, PYTHON=str(old))
    assert out.returncode == 1
    assert f"Signmap needs Python 3.11 or newer; PYTHON={old} is Python 3.9." in out.stderr
    out = find_python(repo, bin_dir, PYTHON="/nonexistent/python")
    assert out.returncode == 1 and "PYTHON=/nonexistent/python does not run" in out.stderr


def test_a_venv_of_an_old_python_is_recreated(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3.12", "3.12", log)
    fake_python(repo / ".venv" / "bin" / "python", "3.9", log)
    out = run(repo, bin_dir, "source scripts/venv.sh && ensure_venv")
    assert out.returncode == 0, out.stderr
    assert "the existing .venv was made by Python 3.9; Signmap needs 3.11 or newer: recreating " \
        f".venv with {bin_dir / 'python3.12'}" in out.stderr
    assert log.read_text() == "python3.12 -m venv --clear .venv\n"
    assert "echo 3.12" in (repo / ".venv" / "bin" / "python").read_text()


def test_a_good_venv_is_kept(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3.12", "3.12", log)
    fake_python(repo / ".venv" / "bin" / "python", "3.11", log)
    out = run(repo, bin_dir, "source scripts/venv.sh && ensure_venv")
    assert out.returncode == 0 and out.stderr == ""
    assert log.read_text() == ""


def test_run_sh_without_a_suitable_python_stops_with_the_message(sandbox):
    repo, bin_dir, log = sandbox
    out = script(repo, bin_dir, "run.sh")
    assert out.returncode == 1
    assert "Signmap needs Python 3.11 or newer" in out.stderr
    assert "command not found" not in out.stderr and log.read_text() == ""


def test_run_sh_creates_the_venv_and_ends_with_how_to_use_signmap(sandbox, tmp_path):
    repo, bin_dir, log = sandbox
    venv_bin = tmp_path / "venv-bin"  # what `pip install` would put there: a fake signmap
    _executable(venv_bin / "signmap", f'#!/bin/sh\necho "signmap $*" >> {log}\n')
    fake_python(bin_dir / "python3.13", "3.13", log, venv_bin)
    run_dir = tmp_path / "run"
    out = script(repo, bin_dir, "run.sh", RUN_DIR=str(run_dir))
    assert out.returncode == 0, out.stderr
    calls = log.read_text().splitlines()
    assert calls[0] == "python3.13 -m venv --clear .venv"
    assert calls[1] == "python -m pip install --quiet -e .[test]"
    assert calls[2] == f"signmap synth --seed 0 --frames 120 --turns 1 --out {run_dir}/journey"
    assert calls[3] == (f"signmap process {run_dir}/journey/bundle.zip "
                        f"--out {run_dir}/signs.geojson")
    assert calls[4].startswith("python -m bench.compare")
    tail = out.stdout.rstrip().splitlines()[-4:]
    assert tail == [f"signmap is installed in {repo}/.venv. To use it from your shell:",
                    f"  source {repo}/.venv/bin/activate     # then: signmap --help",
                    "or call it by its path, without activating:",
                    f"  {repo}/.venv/bin/signmap --help"]


def test_test_sh_uses_any_suitable_python(sandbox):
    repo, bin_dir, log = sandbox
    fake_python(bin_dir / "python3", "3.12", log)
    out = script(repo, bin_dir, "test.sh", "-m", "not slow")
    assert out.returncode == 0, out.stderr
    assert log.read_text().splitlines() == [
        "python3 -m venv --clear .venv",
        "python -m pip install --quiet -e .[test]",
        "python -m pytest -ra -n auto --dist loadfile -m not slow",  # a worker per core
    ]
    log.write_text("")
    out = script(repo, bin_dir, "test.sh", SIGNMAP_TEST_WORKERS="0")
    assert out.returncode == 0, out.stderr
    assert log.read_text().splitlines()[-1] == "python -m pytest -ra -n 0 --dist loadfile"


def test_demo_sh_checks_for_curl_and_jq_first(sandbox):
    repo, bin_dir, log = sandbox
    out = script(repo, bin_dir, "demo.sh")
    assert out.returncode == 1
    assert out.stderr.splitlines()[0] == "scripts/demo.sh needs curl and jq; missing: curl jq"
    assert "apt-get install curl jq" in out.stderr
    _executable(bin_dir / "curl", "#!/bin/sh\nexit 0\n")
    out = script(repo, bin_dir, "demo.sh")
    assert out.stderr.splitlines()[0] == "scripts/demo.sh needs curl and jq; missing: jq"
    _executable(bin_dir / "jq", "#!/bin/sh\nexit 0\n")
    out = script(repo, bin_dir, "demo.sh")
    assert out.returncode == 1
    assert "needs signmap installed in .venv: run 'bash scripts/run.sh' first" in out.stderr
    assert log.read_text() == ""
