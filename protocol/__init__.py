"""fleetgate wire protocol (v1): pydantic models for robot, gateway and operator messages."""
