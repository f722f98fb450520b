"""The wire: transports, connection sessions, plain HTTP, the HTTP API routing, auth and TLS."""
