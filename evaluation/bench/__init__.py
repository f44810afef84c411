"""Speed micro-benchmarks (not tests): the photometric factors (:mod:`.factors`), the
batched normal integration (:mod:`.integration`) and the monocular VO (:mod:`.vo`)."""
