"""The port check `neuraldem serve` makes before it starts: a port in use ends in one line naming a free one."""

from __future__ import annotations

import errno
import socket

from neuraldem.errors import ConfigError

SEARCH = 50  # ports above the asked one tried for a suggestion


def port_is_free(host: str, port: int) -> bool:
    """Whether a server could listen on (host, port) now (bound and released at once)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError as err:
            if err.errno in (errno.EADDRINUSE, errno.EACCES):
                return False
            raise
    return True


def free_port(host: str = "127.0.0.1") -> int:
    """A port the system says is free now (for tests and `port=0`)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def suggest_port(host: str, taken: int) -> int:
    """The first free port above `taken` (else any free one)."""
    for port in range(taken + 1, min(taken + 1 + SEARCH, 65536)):
        if port_is_free(host, port):
            return port
    return free_port(host)


def check_port(host: str, port: int) -> int:
    """`port` when free (0: a free one picked now); a port in use is a ConfigError that names another."""
    if not 0 <= port <= 65535:
        raise ConfigError(f"port={port} is invalid", "give a port between 1024 and 65535, e.g. port=5006")
    if port == 0:
        return free_port(host)
    try:
        free = port_is_free(host, port)
    except OSError as err:
        raise ConfigError(f"cannot listen on {host}:{port} ({err.strerror})", "check host=") from None
    if not free:
        raise ConfigError(f"port {port} is in use on {host} (another server is listening there)",
                          f"try port={suggest_port(host, port)}")
    return port
