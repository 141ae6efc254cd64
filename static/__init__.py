"""The dashboard's page (plain HTML, JS and CSS, no build step), shipped as package data of app.static."""
