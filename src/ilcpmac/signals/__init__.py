"""Signal design and position-domain analysis."""
