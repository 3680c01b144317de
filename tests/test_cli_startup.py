"""The console commands start fast and answer Ctrl-C at start-up with one line.

Building the parsers (every ``--help``) imports no heavy library: each sub-command imports what it
needs when it runs, and the choices and defaults that ``--help`` shows come from the light modules that
own them (:mod:`curbside.localize.runconstants`, :mod:`curbside.localize.platforms`,
:mod:`curbside.osmseg.config`), which the heavy ones import; ``localize --help`` does not even import
``dataclasses``. A Ctrl-C that lands while modules import exits 130 with ``PROG: interrupted`` and no
traceback: the tests make an import hang (a meta-path finder that sleeps when asked for one module) and
send SIGINT once the child says it is in that import, so they do not depend on timing.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

WALK = Path(__file__).parent / "data" / "sessions" / "walk.gpx"

#: What ``--help`` must not import: each costs tenths of a second to seconds at start-up.
HEAVY = ("numpy", "pandas", "scipy", "torch", "matplotlib", "geopandas", "shapely", "osmnx", "dask", "numba",
         "pyproj", "h5py")

# Every ``--help`` of the commands named in argv, in this process; prints the top-level packages imported.
_EVERY_HELP = textwrap.dedent(
    """
    import argparse, contextlib, importlib, io, json, sys

    def commands(module):
        seen = {}
        run_cli, module.run_cli = module.run_cli, lambda prog, parser, argv: seen.setdefault("p", parser)
        module.main([])
        module.run_cli = run_cli
        (sub,) = [a for a in seen["p"]._actions if isinstance(a, argparse._SubParsersAction)]
        return list(sub.choices)

    for module in (importlib.import_module(f"curbside.cli.{prog}") for prog in sys.argv[1:]):
        for argv in (["--help"], *([name, "--help"] for name in commands(module))):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
                module.main(argv)
    print(json.dumps(sorted({name.partition(".")[0] for name in sys.modules})))
    """
)


def _imported_by_every_help(*progs: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", _EVERY_HELP, *progs], capture_output=True, text=True,
                         check=True, timeout=120).stdout
    return set(json.loads(out))


def test_no_help_imports_a_heavy_library():
    """``localize --help``, ``osmseg --help`` and every sub-command's ``--help``, in a fresh process."""
    imported = _imported_by_every_help("localize", "osmseg") & set(HEAVY)
    assert not imported, f"--help imports {sorted(imported)}"


def test_localize_help_imports_no_dataclasses():
    """``import dataclasses`` (inspect, ast, dis) and the frozen dataclasses made at import would add about
    a fifth to ``localize --help``: its parsers quote :mod:`curbside.localize.runconstants`, not the
    config dataclasses."""
    assert "dataclasses" not in _imported_by_every_help("localize")


def test_the_quoted_defaults_are_the_configs_defaults():
    """Each field of the configs whose defaults ``--help`` quotes takes its default from
    :mod:`curbside.localize.runconstants`, so that what ``--help`` says is what a run does."""
    from curbside.evaluate.runner import METHODS
    from curbside.localize import runconstants
    from curbside.localize.ronin.stream import RoninStreamConfig
    from curbside.localize.runconfig import FamiliarVelocityConfig, UnseenVelocityConfig

    for config, quoted in ((UnseenVelocityConfig(), runconstants.UNSEEN_VELOCITY_DEFAULTS),
                           (FamiliarVelocityConfig(), runconstants.FAMILIAR_VELOCITY_DEFAULTS)):
        assert dataclasses.asdict(config) == vars(quoted), type(config).__name__
    assert RoninStreamConfig().stride == runconstants.RONIN_STRIDE
    assert METHODS == runconstants.MODES


# The console script's own code (``from curbside.cli.PROG import main; sys.exit(main())``), after a
# finder that hangs the first import of HANG, once it has said so on stdout.
_HANGING_START = textwrap.dedent(
    """
    import os, sys, time

    class Hang:
        def find_spec(self, name, path=None, target=None):
            if name == {hang!r}:
                os.write(1, b"importing\\n")
                time.sleep(120)
            return None

    sys.meta_path.insert(0, Hang())
    sys.argv = {argv!r}
    from curbside.cli.{prog} import main
    sys.exit(main())
    """
)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process is POSIX")
@pytest.mark.parametrize(
    ("prog", "argv", "hang"),
    [
        ("localize", ["--help"], "curbside.cli.localize_run"),  # while the parsers are built
        ("osmseg", ["--help"], "curbside.cli.parameters"),
        # while the command's modules import, once its inputs passed the checks that come before them
        ("localize", ["run", str(WALK), "-o", "OUT"], "numpy"),
        ("osmseg", ["build", "-o", "OUT.geojson"], "numpy"),
    ],
    ids=["localize-parsers", "osmseg-parsers", "localize-run-imports", "osmseg-build-imports"],
)
def test_ctrl_c_at_start_up_says_interrupted(tmp_path, prog, argv, hang):
    script = _HANGING_START.format(hang=hang, argv=[prog, *argv], prog=prog)
    env = {**os.environ, "CURBSIDE_DEBUG": "0"}
    with subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, env=env) as proc:
        try:
            line = proc.stdout.readline()  # the child is in the hanging import
            if line == b"importing\n":
                proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
    assert line == b"importing\n", f"the child never reached {hang}: {err.decode()}"
    assert err.decode() == f"{prog}: interrupted\n"
    assert proc.returncode == 130
    assert not any(tmp_path.iterdir()), "nothing is written"
