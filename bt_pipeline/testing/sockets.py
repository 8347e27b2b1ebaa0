"""Listening sockets of a process tree, for the tests that every socket bt opens is loopback."""

from __future__ import annotations

import ipaddress

import psutil


def listening(pid: int) -> list[tuple[int, str, int]]:
    """(pid, address, port) of every listening inet socket of `pid` and its descendants."""
    try:
        root = psutil.Process(pid)
        tree = [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []
    found = []
    for process in tree:
        try:
            connections = process.net_connections(kind="inet")
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        found += [
            (process.pid, c.laddr.ip, c.laddr.port)
            for c in connections
            if c.status == psutil.CONN_LISTEN
        ]
    return found


def is_loopback_address(address: str) -> bool:
    """Whether `address` is a loopback address, IPv4-mapped ones (``::ffff:127.0.0.1``) too."""
    ip = ipaddress.ip_address(address.split("%")[0])
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback
