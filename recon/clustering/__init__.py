"""Clustering (paper section 2.2): each point assigned to body sections by distance, refined per cell by Otsu thresholds."""
