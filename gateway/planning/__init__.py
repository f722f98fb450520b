"""Pure planning layer: grids, MovingAI IO, generators, 1-robust CBS, plan validation.

No I/O beyond explicit file readers, no clock (time limits come in as a `Deadline`), no asyncio,
websockets or pydantic.
"""
