"""One FastAPI router per resource of the HTTP API (each ``router(ctx)``, see :mod:`workers.http.app`)."""
