"""The HTTP API of the service (FastAPI): ``service.api.app.create_app`` builds it."""
