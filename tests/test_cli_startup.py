"""The console commands start fast and answer Ctrl-C at start-up with one line.

Building the parsers (every ``--help``) imports no heavy library: each sub-command imports what it
needs when it runs, and the choices and defaults that ``--help`` shows come from
:mod:`curbside.cli.defaults`, whose copies are checked here against the modules that own them. A
Ctrl-C that lands while modules import exits 130 with ``PROG: interrupted`` and no traceback: the
tests make an import hang (a meta-path finder that sleeps when asked for one module) and send SIGINT
once the child says it is in that import, so they do not depend on timing.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from curbside.cli import defaults

#: What ``--help`` must not import: each costs tenths of a second to seconds at start-up.
HEAVY = ("numpy", "pandas", "scipy", "torch", "matplotlib", "geopandas", "shapely", "osmnx", "dask", "numba",
         "pyproj", "h5py")

_EVERY_HELP = textwrap.dedent(
    """
    import argparse, contextlib, io, json, sys
    from curbside.cli import localize, osmseg

    def commands(module):
        seen = {}
        run_cli, module.run_cli = module.run_cli, lambda prog, parser, argv: seen.setdefault("p", parser)
        module.main([])
        module.run_cli = run_cli
        (sub,) = [a for a in seen["p"]._actions if isinstance(a, argparse._SubParsersAction)]
        return list(sub.choices)

    for module in (localize, osmseg):
        for argv in (["--help"], *([name, "--help"] for name in commands(module))):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
                module.main(argv)
    print(json.dumps(sorted({name.partition(".")[0] for name in sys.modules})))
    """
)


def test_no_help_imports_a_heavy_library():
    """``localize --help``, ``osmseg --help`` and every sub-command's ``--help``, in a fresh process."""
    out = subprocess.run([sys.executable, "-c", _EVERY_HELP], capture_output=True, text=True, check=True,
                         timeout=120).stdout
    imported = set(json.loads(out)) & set(HEAVY)
    assert not imported, f"--help imports {sorted(imported)}"


def test_the_shown_defaults_are_their_owners():
    from curbside.evaluate.runner import METHODS
    from curbside.io import OVERWRITE_FILE_HELP
    from curbside.localize import runconfig
    from curbside.localize.readers._platform import PLATFORM_OPTIONS
    from curbside.localize.ronin.stream import RoninStreamConfig
    from curbside.osmseg.build import READ_MARGIN_M

    for name in ("MODES", "VELOCITY_SOURCES", "UNSEEN_VELOCITY_MODES", "FAMILIAR_VELOCITY_MODES"):
        assert tuple(getattr(runconfig, name)) == getattr(defaults, name), name
    for shown, owner in ((defaults.UNSEEN_VELOCITY, runconfig.UnseenVelocityConfig()),
                         (defaults.FAMILIAR_VELOCITY, runconfig.FamiliarVelocityConfig())):
        assert vars(shown) == {key: getattr(owner, key) for key in vars(shown)}, type(owner).__name__
    assert tuple(METHODS) == defaults.METHODS
    assert tuple(PLATFORM_OPTIONS) == defaults.PLATFORM_OPTIONS
    assert defaults.READ_MARGIN_M == READ_MARGIN_M
    assert RoninStreamConfig().stride == defaults.RONIN_STRIDE
    assert defaults.OVERWRITE_FILE_HELP == OVERWRITE_FILE_HELP


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
        ("localize", ["run", "no-such-session", "-o", "OUT"], "numpy"),  # while the command's modules import
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
