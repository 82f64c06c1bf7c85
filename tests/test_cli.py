import subprocess
import sys

import hsmap


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "hsmap.cli", *args], capture_output=True, text=True)


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0
    assert r.stdout.strip() == f"hsmap {hsmap.__version__}"


def test_help_lists_commands():
    r = run_cli("--help")
    assert r.returncode == 0
    for cmd in ("simulate", "slam", "map", "segment", "evaluate", "reproduce"):
        assert cmd in r.stdout


def test_a_negative_vector_is_a_flags_value():
    """``--extrinsic2d -0.04,0,0`` (fr079's offset, as the README gives it) is the flag's value, as ``=-0.04,0,0``
    is; argparse alone takes a value that starts with a minus sign for a flag unless it is a plain number."""
    from hsmap.cli import build_parser

    p = build_parser()
    for form in (["--extrinsic2d", "-0.04,0,0"], ["--extrinsic2d=-0.04,0,0"]):
        a = p.parse_args(["slam", "fr079.bag", "--out", "o", *form, "--seed", "1"])
        assert a.extrinsic2d == "-0.04,0,0" and a.seed == 1 and a.out == "o"
    a = p.parse_args(["slam", "x.bag", "--out", "o", "--extrinsic3d", "-.1,0,1.6,0,0,-1.57", "--dof", "6"])
    assert a.extrinsic3d == "-.1,0,1.6,0,0,-1.57" and a.dof == 6
    assert p.parse_args(["map", "x.bag", "--out", "o", "--slice", "-0.2,0.1"]).slice == "-0.2,0.1"
    # a flag that takes no value leaves the next argument alone
    r = run_cli("slam", "x.bag", "--out", "o", "--quiet", "-0.04,0,0")
    assert r.returncode == 2 and "unrecognized arguments: -0.04,0,0" in r.stderr


def test_a_closed_stdout_is_not_an_error():
    """``hsmap config show | head -1``: the reader going away ends the command quietly with status 0."""
    import subprocess
    import sys

    cmd = f"{sys.executable} -m hsmap config show | head -1"
    proc = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("[slam]") and "error" not in proc.stderr
