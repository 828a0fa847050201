"""Study instruments: an independent simulator for coverage and confusion studies (docs/uncertainty.md)."""
