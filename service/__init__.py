"""The HTTP render service (FastAPI): a thin layer over `renderer`; the dependency arrow points
service -> renderer only."""
