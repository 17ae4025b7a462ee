from sianms_cli.cli import main

main()
