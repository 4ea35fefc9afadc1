"""Surfaces (paper section 3): each section's points meshed on its own chart by 2D Delaunay, under the air rules;
beyond the paper, the points no section explains (`complete`) and the closed surface (`closed`)."""
