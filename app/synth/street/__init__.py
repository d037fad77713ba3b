"""The street a synthetic journey drives: ``road`` (the centreline: straights and arcs), ``layout``
(where signs, building fronts and props stand), ``textures`` (procedural facades, ground and sign
faces) and ``world`` (all of them built from a seed, with the signs' ground truth)."""
