"""A port in use ends `neuraldem serve` in one line that names a free port; the check comes before any loading."""

from __future__ import annotations

import socket

import pytest

from neuraldem.errors import ConfigError
from neuraldem.serve.ports import check_port, free_port, port_is_free


@pytest.fixture
def busy_port():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        yield s.getsockname()[1]


def test_a_port_in_use_names_a_free_one(busy_port: int):
    with pytest.raises(ConfigError, match=rf"port {busy_port} is in use on 127.0.0.1") as err:
        check_port("127.0.0.1", busy_port)
    suggested = int(str(err.value).split("try port=")[1])
    assert suggested != busy_port and port_is_free("127.0.0.1", suggested)


def test_a_free_port_is_kept_and_port_0_picks_one():
    port = free_port()
    assert check_port("127.0.0.1", port) == port
    assert check_port("127.0.0.1", 0) > 0


def test_serve_on_a_port_in_use_is_one_line_and_exit_2(busy_port: int, capsys):
    from neuraldem.serve.__main__ import main

    with pytest.raises(SystemExit) as stop:
        main([f"port={busy_port}"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert err.startswith(f"neuraldem: error: port {busy_port} is in use") and "try port=" in err


@pytest.mark.parametrize("port", ["-1", "70000"])
def test_an_impossible_port_is_refused(port: str, capsys):
    from neuraldem.serve.__main__ import main

    with pytest.raises(SystemExit) as stop:
        main([f"port={port}"])
    assert stop.value.code == 2 and f"port={port} is invalid" in capsys.readouterr().err
