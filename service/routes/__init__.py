"""Thin handlers: http.py (/v1 resources), ws.py (/v1/sessions/{id}/ws), health.py,
docs.py (/docs and /redoc, with their assets served locally)."""
