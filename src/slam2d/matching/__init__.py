"""Scan matchers: align a scan to a map and return the pose, its score and what the search did."""
