//! Built-in analytic sky with a moving sun and passing clouds. (Being written.)
