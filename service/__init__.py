"""The IK service: FastAPI app over ``solver`` (HTTP + WebSocket). Start with
``python -m service``; build apps with ``service.main.create_app(settings)``."""
