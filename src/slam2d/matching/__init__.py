"""Scan matchers: align a scan to a map (or to another scan) and say how well it is constrained."""
