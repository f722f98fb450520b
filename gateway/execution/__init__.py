"""Sans-I/O execution core: ADG, retiming executor, slack monitor, replanning policies.

Nothing here does I/O, reads a clock, or imports asyncio, websockets or pydantic: every input
carries the current time (``now_ms``) and every output leaves through ``Executor.drain()``.
"""
