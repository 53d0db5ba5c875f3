"""Celery worker: a thin task that runs the core pipeline on one job folder."""
