"""The seed's method (seed §4.3, SPEC §5): one visibility bit per pair of sub-elements."""
