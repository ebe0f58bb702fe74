"""ltlnav workers: turn mission specs into artifacts (plans, trained policies, bundles)."""
