"""Shared fixtures: the `stereotac` CLI and the data it makes (a demo run: model and
recordings; pairs exported from them; a built-in stereo capture). Results of the Python
package are compared with the CLI's on the same inputs.

The CLI is `$STEREOTAC_BIN`, else the workspace's `target/{release,debug}/stereotac`.
`$STEREOTAC_DEMO_OUT` may name a finished `stereotac demo --out` folder to reuse (CI
passes its own); otherwise the fixtures run the demo once per session. Without a CLI,
the tests that need one are skipped (and say so)."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

try:
    import stereotac  # noqa: F401
except ImportError as e:  # the sources in python/stereotac/ shadow the installed package
    raise ImportError(
        f"{e}: install the package first (pip install ./python), and run pytest from the "
        "repository root (python -m pytest python/tests): from inside python/, its "
        "source folder, which has no built module, hides the installed one"
    ) from e

REPO = Path(__file__).resolve().parents[2]


def _cli():
    env = os.environ.get("STEREOTAC_BIN")
    if env:
        return Path(env)
    for profile in ("release", "debug"):
        p = REPO / "target" / profile / "stereotac"
        if p.is_file():
            return p
    found = shutil.which("stereotac")
    return Path(found) if found else None


@pytest.fixture(scope="session")
def cli():
    path = _cli()
    if path is None or not path.is_file():
        pytest.skip("no stereotac CLI (set STEREOTAC_BIN or build it: cargo build -p stereotac)")
    return path


def run(cli, *args):
    """Runs the CLI; its output on failure."""
    p = subprocess.run([str(cli), *map(str, args)], capture_output=True, text=True)
    assert p.returncode == 0, f"stereotac {' '.join(map(str, args))}: {p.stderr}"
    return p.stdout


@pytest.fixture(scope="session")
def demo_out(cli, tmp_path_factory):
    given = os.environ.get("STEREOTAC_DEMO_OUT")
    if given and (Path(given) / "model.json").is_file():
        return Path(given)
    out = tmp_path_factory.mktemp("demo")
    run(cli, "demo", "--phases", "4", "--no-stereo", "--out", out, "--force")
    return out


@pytest.fixture(scope="session")
def model_path(demo_out):
    return demo_out / "model.json"


def _exported(cli, recording, folder):
    run(cli, "export", recording, "--pairs", folder)
    pairs = []
    for dx in sorted(folder.glob("*_dx.png")):
        name = dx.name[: -len("_dx.png")]
        dark = folder / f"{name}_dark.png"
        pairs.append((name, dx, folder / f"{name}_dy.png", dark if dark.is_file() else None))
    assert pairs, f"{recording}: no dx/dy pairs exported"
    return pairs


@pytest.fixture(scope="session")
def scene_pairs(cli, demo_out, tmp_path_factory):
    """The demo recording's pairs (the skin at rest, then objects): (name, dx, dy, dark)."""
    return _exported(cli, demo_out / "demo.mcap", tmp_path_factory.mktemp("scene"))


@pytest.fixture(scope="session")
def press_pairs(cli, demo_out, tmp_path_factory):
    """The demo's ball presses, as `calibrate` reads them: (name, dx, dy, dark)."""
    folder = tmp_path_factory.mktemp("presses")
    return folder, _exported(cli, demo_out / "presses.mcap", folder)


@pytest.fixture(scope="session")
def stereo_capture(cli, tmp_path_factory):
    """`stereotac stereo --synthetic 150`: its inputs, calibration and outputs."""
    out = tmp_path_factory.mktemp("stereo")
    run(cli, "stereo", "--synthetic", "150", "--out-dir", out, "--force")
    return out
