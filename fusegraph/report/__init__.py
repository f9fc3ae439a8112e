"""Report: draws the results it is handed (tables, JSON-ready figures, plots, pictures per system, 3D views, TUM files)."""
