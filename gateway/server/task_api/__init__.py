"""The task API for a warehouse system: its routes, its pydantic models, its OpenAPI document."""
