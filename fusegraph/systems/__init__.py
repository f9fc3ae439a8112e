"""End-to-end pipelines per system: Session -> Estimate for every method (ours and the baselines)."""
