"""Figures for the experiments (matplotlib, Agg canvas, no pyplot state)."""
