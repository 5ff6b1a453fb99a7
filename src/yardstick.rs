//! Quality yardsticks for light lists (DESIGN.md) and Debevec's median cut as the peer. (Being written.)
