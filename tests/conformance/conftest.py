"""Fixtures of the conformance tests: the VDA 5050 mode's real mosquitto."""

from tests.vda5050.conftest import broker_url  # noqa: F401 (a fixture, used by name)
