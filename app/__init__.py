"""orbit-emulator: on-orbit contact emulated with two robot arms."""

from app.runs.kernel_cache import forget_stale as _forget_stale

_forget_stale()  # a kernel cache compiled from other sources, before any kernel loads
