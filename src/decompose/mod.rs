//! Decomposition of environment-map frames into directional lights. (Being written.)
