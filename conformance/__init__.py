"""``fleetgate conformance``: check a gateway or a robot against the robot protocol (v2, and v1).

The vendor-facing part of fleetgate: it imports only :mod:`protocol`, websockets and the
standard library. Every check cites a rule of ``docs/protocol.md``.
"""
