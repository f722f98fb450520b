"""fleetgate gateway: planning, execution core, server and operator GUI."""
