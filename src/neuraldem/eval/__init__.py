"""Evaluation: metric functions (shared by ground truth and surrogate), rollouts, plots, VTK export."""
