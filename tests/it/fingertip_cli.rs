//! Fingertip command line: `poke --sphere/--friction/--slide/--steps` (written by the CLI work).
