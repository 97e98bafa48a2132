"""Zenoh endpoints are checked before anything starts: a malformed one is a one-line error
naming the option or key, never a Zenoh traceback or a crash-looping stage."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.config import load_pipeline
from bnptrack.pipeline.endpoints import check_endpoint


@pytest.mark.parametrize("endpoint", ["tcp/127.0.0.1:0", "tls/0.0.0.0:7447", "tcp/10.0.0.5:7447",
                                      "tcp/[::1]:7447", "udp/localhost:7447", "quic/host.example:7447",
                                      "tls/10.0.0.5:7447#iface=eth0", "unixsock-stream//tmp/zenoh.sock"])
def test_documented_endpoint_forms_pass(endpoint):
    check_endpoint(endpoint, "--connect")


@pytest.mark.parametrize("endpoint, fragment", [
    ("garbage", "expected a Zenoh endpoint PROTO/ADDRESS such as tcp/10.0.0.5:7447"),
    ("http/10.0.0.5:7447", "expected a Zenoh endpoint PROTO/ADDRESS"),
    ("tcp/", "expected a Zenoh endpoint PROTO/ADDRESS"),
    ("tcp/10.0.0.5", "expected tcp/HOST:PORT with a port 0-65535"),
    ("tcp/10.0.0.5:99999", "expected tcp/HOST:PORT with a port 0-65535"),
    ("tls/:7447", "expected tls/HOST:PORT with a port 0-65535"),
])
def test_malformed_endpoints_name_the_option(endpoint, fragment):
    with pytest.raises(ValueError) as err:
        check_endpoint(endpoint, "--connect")
    assert str(err.value).startswith(f"--connect {endpoint!r}: {fragment}")


def test_a_pipeline_file_s_endpoint_is_checked_with_its_key(tmp_path):
    with pytest.raises(ValueError, match=r"zenoh\.listen 'tcp/h': expected tcp/HOST:PORT"):
        load_pipeline(None, ["zenoh.listen=['tcp/h']"])


@pytest.mark.parametrize("args, line", [
    (["router", "--listen", "garbage"], "Error: Invalid value for '--listen': 'garbage': expected a Zenoh endpoint"),
    (["monitor", "--run", "x", "--connect", "tcp/x"], "Error: Invalid value for '--connect': 'tcp/x': expected tcp/HOST:PORT"),
    (["stage", "sink", "--run", "r1", "--connect", "garbage"], "Error: Invalid value for '--connect': 'garbage'"),
    (["launch", "--connect", "garbage", "--set", "source.frames=3"], "Error: Invalid value for '--connect': 'garbage': expected a Zenoh endpoint"),
])
def test_commands_refuse_a_malformed_endpoint_before_starting(tmp_path, args, line):
    out = tmp_path / "run"
    extra = ["--out", str(out)] if args[0] == "launch" else []
    res = CliRunner().invoke(main, [*args, *extra])
    assert res.exit_code == 2, res.output
    errors = [ln for ln in res.output.splitlines() if ln.startswith("Error:")]
    assert len(errors) == 1 and errors[0].startswith(line), res.output
    assert "Traceback" not in res.output and not out.exists()


def test_launch_connect_with_a_port_means_a_viewer_on_this_machine(tmp_path):
    from bnptrack.pipeline.ports import free_port

    port = free_port()  # nothing listens there
    res = CliRunner().invoke(main, ["launch", "--connect", str(port), "--out", str(tmp_path / "run")])
    assert res.exit_code == 2, res.output
    assert res.output.strip().startswith(f"Error: no Rerun viewer at rerun+http://127.0.0.1:{port}/proxy")
    assert not (tmp_path / "run").exists()
    res = CliRunner().invoke(main, ["launch", "--connect", "99999", "--out", str(tmp_path / "run")])
    assert res.exit_code == 2 and res.output.strip() == "Error: --connect 99999: a port is 1-65535"
