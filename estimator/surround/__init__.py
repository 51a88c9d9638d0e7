"""Surround analysis (section 5): vehicle detection, the plan view, tracking, the surround map."""
