"""The scenario: its schema as validated, frozen types (one pydantic model per TOML table), loading
from a file, a built-in name or a dict, dotted-key overrides, the TOML round trip, and the
built-in scenarios (``config/scenarios/*.toml``).

Owns: every scenario key, its default, its unit and its error message. Imports nothing of
emfabric: every other layer may import it.
"""
