"""Evaluation: sessions x solvers -> results. Reports and benches over imported or simulated sessions, ablation
studies, tuning (one rule: tuning seeds, or leave-one-recording-out), the runner and the cluster."""
