"""Long measurements behind `make bench`; each section module has run() -> markdown text."""
