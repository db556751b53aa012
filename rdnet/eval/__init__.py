"""Evaluation: image and restoration metrics, tables, figures."""
