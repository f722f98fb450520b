"""Throwaway certificates for TLS tests (trustme): a CA, the gateway's certificate for
127.0.0.1, a client certificate per robot and one from a rogue CA."""

from __future__ import annotations

import ssl
from dataclasses import dataclass
from pathlib import Path

import trustme

from gateway.server.config import TlsConfig
from protocol.tls import client_context, robot_identity


@dataclass
class Certs:
    """PEM files under one directory."""

    ca: Path
    server_cert: Path
    server_key: Path
    robots: dict[int, Path]
    """robot id -> PEM with its client certificate and key."""
    rogue: Path
    """A client certificate for robot 0 signed by another CA."""

    def tls(self, *, require_client_cert: bool = False) -> TlsConfig:
        """The gateway's TLS settings (mutual TLS against ``ca``)."""
        return TlsConfig(cert=self.server_cert, key=self.server_key, client_ca=self.ca,
                         require_client_cert=require_client_cert)

    def client(self, robot: int | None = None, *, rogue: bool = False) -> ssl.SSLContext:
        """A client context trusting ``ca``, presenting robot ``robot``'s certificate."""
        cert = self.rogue if rogue else self.robots[robot] if robot is not None else None
        return client_context(self.ca, cert)


def make_certs(directory: Path, robots: range = range(3)) -> Certs:
    """Issue everything into ``directory``."""
    ca, rogue_ca = trustme.CA(), trustme.CA()
    ca.cert_pem.write_to_path(str(directory / "ca.pem"))
    server = ca.issue_cert("127.0.0.1", "localhost")
    server.cert_chain_pems[0].write_to_path(str(directory / "server.pem"))
    server.private_key_pem.write_to_path(str(directory / "server.key"))
    files: dict[int, Path] = {}
    for r in robots:
        leaf = ca.issue_cert(f"robot-{r}.fleetgate.invalid", common_name=robot_identity(r))
        files[r] = directory / f"robot-{r}.pem"
        leaf.private_key_and_cert_chain_pem.write_to_path(str(files[r]))
    rogue = rogue_ca.issue_cert("robot-0.fleetgate.invalid", common_name=robot_identity(0))
    rogue.private_key_and_cert_chain_pem.write_to_path(str(directory / "rogue.pem"))
    return Certs(directory / "ca.pem", directory / "server.pem", directory / "server.key",
                 files, directory / "rogue.pem")
