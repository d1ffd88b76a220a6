"""A plain (non-editable) install works from any directory: the wheel carries every bundled
scenario as package data, and ``copath scenarios`` / ``copath run e5.5`` / ``copath info``
run from a fresh virtual environment outside the checkout.

The venv takes the heavy dependencies (Zenoh, CasADi, foxglove) from the environment the
tests run in, through a ``.pth`` file naming that environment's site-packages: not from the
machine's system site-packages, which a user's own venv does not have. copath itself comes
only from the wheel: the test checks where it is imported from.
"""

from __future__ import annotations

import os
import pathlib
import shutil
import signal
import site
import subprocess
import sys
import sysconfig
import zipfile

import pytest

from copath.wire.session import free_port, loopback_endpoint

pytestmark = pytest.mark.fleet

REPO = pathlib.Path(__file__).resolve().parents[2]
NETWORK_HINTS = ("NewConnectionError", "Temporary failure in name resolution", "Could not find a version",
                 "No matching distribution", "Network is unreachable")


def _run(argv: list[str], cwd: pathlib.Path, timeout: float) -> subprocess.CompletedProcess:
    """Run a command in its own process group; the whole group is killed on timeout.

    PYTHONPATH is dropped: other tests may have put the checkout on it, and pip would then
    take the checkout for an installed copath."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.Popen(argv, cwd=str(cwd), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=env)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"{' '.join(argv)} timed out after {timeout} s\n{out}\n{err}")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # stragglers of the group, if any
        except ProcessLookupError:
            pass
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> pathlib.Path:
    # build from a clean copy: a build/ left in the checkout could carry stale modules into the wheel
    src = tmp_path_factory.mktemp("src") / "copath"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".git", "build", "*.egg-info", "runs", "__pycache__",
                                                             ".pytest_cache", ".hypothesis", "*.mcap"))
    out = tmp_path_factory.mktemp("wheel")
    res = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(src)], out, 600)
    if res.returncode != 0:
        if any(h in res.stderr for h in NETWORK_HINTS):
            pytest.skip(f"cannot fetch the build backend: {res.stderr.strip().splitlines()[-1]}")
        pytest.fail(f"building the wheel failed:\n{res.stdout}\n{res.stderr}")
    (whl,) = out.glob("copath-*.whl")
    return whl


def test_wheel_carries_every_bundled_scenario(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    configs = REPO / "configs"
    expected = {f"copath_configs/{p.relative_to(configs).as_posix()}" for p in configs.rglob("*")
                if p.is_file() and p.suffix in (".toml", ".csv", ".json")}
    assert expected and expected <= names, sorted(expected - names)
    for pkg in ("copath", "agent", "sim", "orchestrator", "copath_configs"):
        assert f"{pkg}/__init__.py" in names
    assert not any(n.startswith(("tests/", "configs/")) for n in names)


def running_site_packages() -> list[str]:
    """The site-packages of the environment running the tests (a venv's own, or the
    interpreter's, and the user site where it is on), in import order."""
    dirs = [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"], *site.getsitepackages()]
    if site.ENABLE_USER_SITE:
        dirs.append(site.getusersitepackages())
    return [d for d in dict.fromkeys(dirs) if os.path.isdir(d)]


def venv_seeing_running_packages(venv: pathlib.Path) -> pathlib.Path:
    """A venv without system site-packages whose own site-packages ends with a ``.pth`` naming
    :func:`running_site_packages`: the wheel installed into it comes first, the running
    environment's packages after it. Plain path lines: the ``.pth`` files of those folders (an
    editable copath among them) are not run. Returns the venv's bin folder."""
    res = _run([sys.executable, "-m", "venv", str(venv)], venv.parent, 120)
    assert res.returncode == 0, res.stderr
    bin_ = venv / "bin"
    own = _run([str(bin_ / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], venv.parent, 60)
    assert own.returncode == 0, own.stderr
    pathlib.Path(own.stdout.strip(), "zz-running-environment.pth").write_text("\n".join(running_site_packages()) + "\n")
    return bin_


def test_plain_install_runs_a_bundled_scenario_from_another_directory(wheel, tmp_path):
    venv = tmp_path / "venv"
    bin_ = venv_seeing_running_packages(venv)
    res = _run([str(bin_ / "python"), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)], tmp_path, 300)
    assert res.returncode == 0, res.stderr
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = _run([str(bin_ / "python"), "-c", "import copath, orchestrator, copath_configs as c; "
                  "print(copath.__file__); print(orchestrator.__file__); print(c.__file__)"], work, 60)
    assert where.returncode == 0, where.stderr
    assert all(str(venv) in line for line in where.stdout.split()), where.stdout

    res = _run([str(bin_ / "copath"), "scenarios"], work, 120)
    assert res.returncode == 0, res.stderr
    assert "e5.5-column-lemniscate" in res.stdout and str(venv) in res.stdout

    listen = loopback_endpoint(free_port())  # the router listens where it is told (multi-host set-up)
    res = _run([str(bin_ / "copath"), "run", "e5.5", "--set", "run.duration_s=3", "--set", "run.settle_s=1",
                "--set", "network.loss=0.1", "--listen", listen, "--out", "out", "-q", "--no-plots"], work, 400)
    assert res.returncode == 0, f"{res.stdout}\n{res.stderr}"
    assert (work / "out" / "run.mcap").is_file() and (work / "out" / "metrics.json").is_file()
    assert "targets (" in res.stdout

    info = _run([str(bin_ / "copath"), "info", str(work / "out" / "run.mcap")], work, 120)
    assert info.returncode == 0, info.stderr
    assert "Seed:" in info.stdout and "network.loss=0.1" in info.stdout
    assert "Sim time:     3.00 s" in info.stdout and "coordination_error_max_m=" in info.stdout
