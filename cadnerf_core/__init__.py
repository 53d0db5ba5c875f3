"""CAD-NeRF: the method. Imports nothing of the service (no HTTP, Celery, Redis, env)."""

__version__ = "0.1.0"
