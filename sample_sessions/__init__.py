"""The sample sessions, shipped as package data of app.sample_sessions (README.md says what each is)."""
