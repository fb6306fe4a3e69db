//! Video mode of `facecap landmarks` (tracker): `facecap landmarks VIDEO --out DIR`.
