"""``stabjax view``: a busy ``--port`` is a usage error naming the option (exit 2), and Ctrl-C or SIGTERM end
the viewer with the README's statuses (130, 143), not 0 (issue 29)."""
import os
import signal
import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from clirun import TINY, captured
from stabjax.plan.spec import make_plan
from stabjax.run.sweep import run_plan

ROOT = Path(__file__).resolve().parents[2]


def test_a_busy_port_is_a_usage_error_naming_the_option(tmp_path, capsys):
    result = tmp_path / "r.nc"
    result.write_bytes(b"not read: the port is checked first")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", 0))
        held.listen(1)
        port = held.getsockname()[1]
        code, out, err = captured(capsys, "view", result, "--port", port, "--no-browser", "--quit-after", 1)
    assert code == 2, (out, err)
    assert "--port" in err and f"port {port} on 127.0.0.1 is in use" in err, err
    assert "Traceback" not in out + err


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130),
                                        pytest.param(signal.SIGTERM, 143, marks=pytest.mark.slow)])  # the same path
def test_the_viewer_stopped_by_a_signal_exits_with_128_plus_the_signal(tmp_path, sig, status):
    result = tmp_path / "r.nc"
    run_plan(make_plan(tomllib.loads(TINY)), result)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    # a shell's background job ignores SIGINT, and a child inherits that: give the viewer Python's own Ctrl-C
    run = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
           "from stabjax.app.cli import main; main(sys.argv[1:])")
    proc = subprocess.Popen([sys.executable, "-c", run, "view", str(result), "--no-browser", "--quit-after", "120"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline()  # printed once the server listens
        assert "serving" in line, (line, proc.stderr.read() if proc.poll() is not None else "")
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == status, (proc.returncode, out, err)
    assert "stopped" in err and "Traceback" not in err, err
