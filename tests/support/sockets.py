"""The IP sockets a process has open, from /proc (Linux): which are reachable from outside.

``exposed(pid)`` lists the UDP sockets bound and the TCP sockets listening on an address outside
127.0.0.0/8 (0.0.0.0 and :: count as outside: every interface), as ``'udp 0.0.0.0:7400'``.
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path

TCP_LISTEN = '0A'


def _inodes(pid: int) -> set[str]:
    out = set()
    for fd in Path(f'/proc/{pid}/fd').iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith('socket:['):
            out.add(target[8:-1])
    return out


def _address(hex_addr: str) -> tuple[ipaddress._BaseAddress, int]:
    host, port = hex_addr.split(':')
    raw = bytes.fromhex(host)
    if len(raw) == 4:
        ip = ipaddress.IPv4Address(raw[::-1])  # little-endian 32-bit word
    else:  # four little-endian 32-bit words
        ip = ipaddress.IPv6Address(b''.join(raw[i:i + 4][::-1] for i in range(0, 16, 4)))
    return ip, int(port, 16)


def _loopback(ip) -> bool:
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback


def sockets(pid: int) -> list[tuple[str, str, int, bool]]:
    """Return ``(protocol, address, port, listening_or_bound)`` of the process' IP sockets."""
    inodes = _inodes(pid)
    out = []
    for proto in ('udp', 'udp6', 'tcp', 'tcp6'):
        table = Path(f'/proc/{pid}/net/{proto}')
        for line in table.read_text().splitlines()[1:]:
            cols = line.split()
            if cols[9] not in inodes:
                continue
            ip, port = _address(cols[1])
            active = proto.startswith('udp') or cols[3] == TCP_LISTEN
            out.append((proto, str(ip), port, active))
    return out


def exposed(pid: int) -> list[str]:
    """Return the process' UDP binds and TCP listens outside 127.0.0.0/8 (see module doc)."""
    return [f'{proto} {addr}:{port}' for proto, addr, port, active in sockets(pid)
            if active and not _loopback(ipaddress.ip_address(addr))]
