"""``python -m fleetgate``: the ``fleetgate`` command (see :mod:`gateway.cli`)."""
