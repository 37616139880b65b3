"""Mapping: the explorer's own occupancy map, built from laser scans as log-odds evidence
(:mod:`.mapper`), and the correlative scan-to-map matching that corrects a noisy pose before a scan is integrated
(:mod:`.scan_matching`)."""
