"""VDA 5050 (versions 2.0 and 2.1): message models, topics, the grid-to-node mapping and the
sans-I/O master-control session that drives one vehicle for the gateway (see docs/vda5050.md).
Imports nothing of the project outside :mod:`protocol`."""
